//! The lab's effects library: the simulator's effects (docs/effects.md) that a
//! vibration-error campaign can identify, each with the parameters the lab fits, where
//! the fit starts, and the physics in a sentence for the diagnosis.
//!
//! Left out, and why:
//! - `non_gaussian`: the kurtosis is measured (the `kurtosis3` column, the
//!   estimator's output), so the model already uses it; a kurtosis the sensors do not
//!   report is a measurement gap, not a missing effect.
//! - `scale_factor_frequency`: its VE is `0.5 k1 d1A E[sign(a3)(L v3 - v3)]`, micro-g
//!   for real passports (d1A of 15..25 ppm), below any campaign's resolution.
//! - `unit_response`: a 2nd-order low-pass on IA at 1..2 kHz changes the VE of a
//!   campaign's tones (tens to hundreds of Hz) by parts in 1e4 of the IA vibration
//!   power; where it matters it is a special case of `mount_resonance` on IA.

use serde::Serialize;

/// How a parameter is searched.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub enum Search {
    /// Enters the VE change linearly (or nearly): start at 0, least squares finds it.
    Linear,
    /// A grid of starting values (multi-start), then Levenberg-Marquardt.
    Grid(&'static [f64]),
    /// A grid spread log-uniformly over the range of a table variable times
    /// `[lo, hi]` factors (e.g. a resonance frequency around the tested ones).
    AroundVariable {
        variable: &'static str,
        lo: f64,
        hi: f64,
        points: usize,
    },
}

/// One fitted parameter.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ParamSpec {
    /// Key of the effect's `[[effect]]` table.
    pub name: &'static str,
    /// Scale of the parameter (its typical magnitude), for numerical derivatives.
    pub scale: f64,
    /// Allowed range (the effect's own validation range, or narrower).
    pub bounds: (f64, f64),
    pub search: Search,
}

/// A candidate effect.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Candidate {
    pub kind: &'static str,
    /// The physics, in a sentence, for the diagnosis.
    pub physics: &'static str,
    /// What in the residual points to it.
    pub signature: &'static str,
    pub params: &'static [ParamSpec],
    /// Fixed keys of its table, as TOML (e.g. the axes it acts on).
    pub fixed: &'static str,
}

const Q_GRID: &[f64] = &[0.7, 1.5, 3.0, 8.0];
const TAU_GRID: &[f64] = &[1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 0.1];
const PHASE_GRID: &[f64] = &[-135.0, -90.0, -45.0, 0.0, 45.0, 90.0, 135.0, 180.0];
const RANGE_GRID: &[f64] = &[
    0.5, 0.75, 1.0, 1.25, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 16.0, 20.0,
    30.0, 40.0,
];

/// Every candidate, in a fixed order.
pub static LIBRARY: &[Candidate] = &[
    Candidate {
        kind: "mount_resonance",
        physics: "the suspension between the vibration sensor and the accelerometer is a resonance: the unit sees the measured vibration times |T(f)|, amplified near the natural frequency and attenuated above it",
        signature: "the residual depends on the tone frequency, peaking near one frequency, and grows with the amplitude as the VE does",
        params: &[
            ParamSpec {
                name: "freq_hz",
                scale: 1.0,
                bounds: (0.1, 1e5),
                search: Search::AroundVariable {
                    variable: "freq_hz",
                    lo: 0.5,
                    hi: 2.0,
                    points: 12,
                },
            },
            ParamSpec {
                name: "q",
                scale: 0.1,
                bounds: (0.05, 1000.0),
                search: Search::Grid(Q_GRID),
            },
        ],
        fixed: "",
    },
    Candidate {
        kind: "axis_phase",
        physics: "the axes do not vibrate in phase (rocking and torsional modes): the IA x OA and IA x PA rectification goes with cos(phi3 - phi1), not 1 as the papers assume",
        signature: "the residual appears only where IA and a cross axis vibrate together, and scales with m31 aB3 aB1 (m32 aB3 aB2)",
        params: &[
            ParamSpec {
                name: "phase_x_deg",
                scale: 1.0,
                bounds: (-360.0, 360.0),
                search: Search::Grid(PHASE_GRID),
            },
            ParamSpec {
                name: "phase_y_deg",
                scale: 1.0,
                bounds: (-360.0, 360.0),
                search: Search::Grid(PHASE_GRID),
            },
        ],
        fixed: "",
    },
    Candidate {
        kind: "vibropendulous",
        physics: "the servo lags at vibration frequencies, so the pendulum swings by c HP[a3] and tilts the input axis towards PA: out += theta a2 (the vibropendulous error)",
        signature: "the residual appears where IA and PA vibrate together, and rises with frequency through the servo's high-pass (time constant tau)",
        params: &[
            ParamSpec {
                name: "c_rad_per_g",
                scale: 1e-5,
                bounds: (-0.1, 0.1),
                search: Search::Linear,
            },
            ParamSpec {
                name: "tau_s",
                scale: 1e-5,
                bounds: (1e-6, 10.0),
                search: Search::Grid(TAU_GRID),
            },
        ],
        fixed: "",
    },
    Candidate {
        kind: "anisoelastic",
        physics: "unequal compliance of the pendulum suspension along OA and PA adds k_ae a1 a2 (an OA x PA cross-coupling the conversion function lacks)",
        signature: "the residual appears where OA and PA vibrate together, proportional to E[v1 v2], independent of IA",
        params: &[ParamSpec {
            name: "k_ae_per_g",
            scale: 1e-6,
            bounds: (-0.01, 0.01),
            search: Search::Linear,
        }],
        fixed: "",
    },
    Candidate {
        kind: "saturation",
        physics: "the torquer saturates: the output is clipped to +-range, which rectifies when vibration and flight acceleration push one side past the range",
        signature: "the residual appears abruptly above an amplitude (plus |aL3|) threshold, with the sign of aL3",
        params: &[ParamSpec {
            name: "range_g",
            scale: 0.01,
            bounds: (0.1, 1e4),
            search: Search::Grid(RANGE_GRID),
        }],
        fixed: "",
    },
    Candidate {
        kind: "high_order_nonlinearity",
        physics: "the conversion function has terms beyond k5: out += k6 a3^6 + k7 a3^7",
        signature: "the residual grows as the 6th power of the IA amplitude (15 k6 aL3^4 aB3^2 / 2 ... ) and changes with aL3 through the odd k7 term",
        params: &[
            ParamSpec {
                name: "k6_ppm_per_g5",
                scale: 1e-3,
                bounds: (-1e4, 1e4),
                search: Search::Linear,
            },
            ParamSpec {
                name: "k7_ppm_per_g6",
                scale: 1e-3,
                bounds: (-1e4, 1e4),
                search: Search::Linear,
            },
        ],
        fixed: "",
    },
    Candidate {
        kind: "heating",
        physics: "vibration dissipates power in the unit and its bias follows through a thermal lag: a bias c E[v3^2] (1 - tau/T (1 - exp(-T/tau))) over a record of length T",
        signature: "the residual follows the IA vibration power (aB3^2/2 + sigma3^2) whatever aL3, the same for every orientation",
        params: &[ParamSpec {
            name: "c_g_per_g2",
            scale: 1e-7,
            bounds: (-0.1, 0.1),
            search: Search::Linear,
        }],
        // With one record length T the lab cannot separate c from tau: it fits the
        // steady-state coefficient (tau much shorter than the records).
        fixed: "tau_s = 1e-6",
    },
    Candidate {
        kind: "sensor_error",
        physics: "the vibration sensor's sensitivity is off by a relative gain error g: the model is fed (1 + g) times the true vibration, so every rectified term is mis-scaled",
        signature: "the residual is the model's own VE scaled: proportional to the VE's derivative with respect to the amplitude (about -2 g x the quadratic terms)",
        params: &[ParamSpec {
            name: "gain_error",
            scale: 1e-3,
            bounds: (-0.5, 0.5),
            search: Search::Linear,
        }],
        fixed: "",
    },
];

/// The candidate of `kind`.
pub fn candidate(kind: &str) -> Option<&'static Candidate> {
    LIBRARY.iter().find(|c| c.kind == kind)
}

/// The kinds of the library.
pub fn kinds() -> Vec<&'static str> {
    LIBRARY.iter().map(|c| c.kind).collect()
}
