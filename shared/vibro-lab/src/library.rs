//! The lab's effects library: every effect of the simulator (docs/effects.md), each
//! with the parameters the lab fits, where the fit starts, the physics in a sentence
//! for the diagnosis, and whether its mean formula needs the random part's spectrum.
//!
//! What a campaign needs to identify the harder ones:
//! - `non_gaussian`: rows with a random part whose true kurtosis differs from the
//!   `kurtosis3` the table states (a kurtosis the sensors do not report, or report
//!   wrongly); the fitted `kurtosis` is the IA random part's true one.
//! - `scale_factor_frequency`: its VE is `0.5 k1 d1A E[sign(a3)(L v3 - v3)]`: micro-g
//!   for real passports (d1A of 15..25 ppm), so it needs a VE resolution well below a
//!   micro-g, IA amplitudes above |aL3| and tones on both sides of the corner.
//! - `unit_response`: a 2nd-order low-pass on IA at 1..2 kHz changes the VE of tones
//!   of tens to hundreds of Hz by parts in 1e4 of the IA vibration power; the campaign
//!   needs tones near the natural frequency (and IA with OA or PA, whose phase against
//!   IA pins the damping).
//!
//! The filtering effects (`needs_spectrum`) cannot be evaluated on a random part
//! without its spectrum (`band_lo_hz`/`band_hi_hz`, or a flight window's bands).

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
    /// Whether its mean formula filters the vibration over frequency, so that on a
    /// row with a random part it needs the part's spectrum (the effect's
    /// `mean_shift_g` fails on a random part without `psd_unit`): such a candidate can
    /// be fitted only on the rows that are tone-only or carry a spectrum.
    pub needs_spectrum: bool,
    /// Whether it changes what every other effect sees (the vibration through a mount
    /// or a servo loop, the phases between axes, the sensor's reading): beside chosen
    /// effects, their nonlinear parameters must move with it (a saturation's range
    /// with a sensor's gain), so a screening that holds them cannot show what it
    /// explains (`diagnose`'s rounds refit it with every parameter free).
    pub acts_on_inputs: bool,
}

/// A frequency's start grid: 12 values log-spaced from half the lowest tested tone
/// frequency to twice the highest (a resonance, a loop's natural frequency, a corner).
const AROUND_TONES: Search = Search::AroundVariable {
    variable: "freq_hz",
    lo: 0.5,
    hi: 2.0,
    points: 12,
};
const Q_GRID: &[f64] = &[0.7, 1.5, 3.0, 8.0];
/// Damping ratios from a sharp to an overdamped servo loop (real units: 0.3..0.7).
const ZETA_GRID: &[f64] = &[0.1, 0.3, 0.6, 1.0];
/// Kurtoses from mildly to strongly bursty (the scale-mixture family: 3..30).
const KURTOSIS_GRID: &[f64] = &[4.0, 6.0, 10.0, 20.0];
/// `lambda_hf` below and above 1: the VE is linear in `lambda_hf - 1` (module doc of
/// the effect), so one start on each side is enough.
const LAMBDA_GRID: &[f64] = &[0.7, 1.5];
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
                search: AROUND_TONES,
            },
            ParamSpec {
                name: "q",
                scale: 0.1,
                bounds: (0.05, 1000.0),
                search: Search::Grid(Q_GRID),
            },
        ],
        fixed: "",
        needs_spectrum: true,
        acts_on_inputs: true,
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
        needs_spectrum: false,
        acts_on_inputs: true,
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
        needs_spectrum: true,
        acts_on_inputs: false,
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
        needs_spectrum: false,
        acts_on_inputs: false,
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
        needs_spectrum: false,
        acts_on_inputs: false,
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
        needs_spectrum: false,
        acts_on_inputs: false,
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
        needs_spectrum: false,
        acts_on_inputs: false,
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
        needs_spectrum: false,
        acts_on_inputs: true,
    },
    Candidate {
        kind: "unit_response",
        physics: "the accelerometer's servo loop is a 2nd-order low-pass H(f) on its input axis: the conversion function sees |H| aB3, shifted in phase by arg H against OA and PA, so every IA rectification term is mis-scaled near the natural frequency",
        signature: "the residual depends on the tone frequency as |H(f)|^2 - 1 on rows vibrated along IA (rising towards the natural frequency, about (1 - 2 zeta^2)(f/f0)^2 below it) and, through cos(arg H), on the IA x OA and IA x PA rows",
        params: &[
            ParamSpec {
                name: "natural_freq_hz",
                scale: 1.0,
                bounds: (1.0, 1e6),
                search: AROUND_TONES,
            },
            ParamSpec {
                name: "damping_ratio",
                scale: 0.01,
                bounds: (0.01, 10.0),
                search: Search::Grid(ZETA_GRID),
            },
        ],
        fixed: "",
        needs_spectrum: true,
        acts_on_inputs: true,
    },
    Candidate {
        kind: "non_gaussian",
        physics: "the random vibration is burstier than the table states: its IA part is a Gaussian scale mixture of kurtosis K (not kurtosis3) at the same PSD, so E[x^4] = K sigma^4 moves the k4 and k5 terms and the asymmetry's E|a3|",
        signature: "the residual appears only on rows with a random part, grows as (k4 + 5 k5 aL3)(K - kurtosis3) sigma3^4, and is larger where the stated kurtosis3 is lower",
        params: &[ParamSpec {
            name: "kurtosis",
            scale: 0.1,
            bounds: (3.0, 30.0),
            search: Search::Grid(KURTOSIS_GRID),
        }],
        // One kurtosis for every body axis: the table states the IA's alone
        // (`kurtosis3`), and the OA and PA kurtoses enter the VE only through the
        // covariances' common-burst factor (1 for equal kurtoses), which a campaign
        // cannot separate from the measured covariances; `kurtosis_x`..`_z` stay unset.
        fixed: "",
        needs_spectrum: false,
        acts_on_inputs: false,
    },
    Candidate {
        kind: "scale_factor_frequency",
        physics: "the scale factor depends on frequency, lambda(f) a first-order shelf from 1 at DC to lambda_hf above a corner; through the scale-factor asymmetry of [P1 (1)] the IA vibration it passes rectifies: VE = 0.5 k1 d1A E[sign(a3)(L v3 - v3)]",
        signature: "the residual is proportional to the IA amplitude (not its square) times (lambda_hf - 1) f^2/(f^2 + fc^2), largest at aL3 = 0 and zero where |aL3| exceeds the IA amplitude (sign(a3) then constant); micro-g for real passports",
        params: &[
            ParamSpec {
                name: "corner_hz",
                scale: 1.0,
                bounds: (0.1, 1e6),
                search: AROUND_TONES,
            },
            // The VE is k1 d1A (lambda_hf - 1) times a known function: with the
            // passport's d1A taken as exact, the campaign pins lambda_hf (a wrong d1A
            // scales lambda_hf - 1 by its ratio to the true one).
            ParamSpec {
                name: "lambda_hf",
                scale: 0.01,
                bounds: (0.01, 10.0),
                search: Search::Grid(LAMBDA_GRID),
            },
        ],
        fixed: "",
        needs_spectrum: true,
        acts_on_inputs: false,
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

#[cfg(test)]
mod tests {
    use super::*;
    use vibro_effects::model::build_effects;
    use vibro_effects::predict::{effect_shifts_g, flat_passport, sensor_rms_factor};
    use vibro_physics::passport::Passport;
    use vibro_physics::vibration::{PsdBand, Vibration};

    fn al15() -> Passport {
        flat_passport(&vibro_config::resolve_passport("AL-15").unwrap()).unwrap()
    }

    /// A value of each parameter inside its search: the first start of a grid, 50 Hz
    /// for a frequency, the scale for a linear one (nonzero, so the effect acts).
    fn representative(p: &ParamSpec) -> f64 {
        let x = match p.search {
            Search::Linear => p.scale,
            Search::Grid(g) => g[0],
            Search::AroundVariable { .. } => 50.0,
        };
        x.clamp(p.bounds.0, p.bounds.1)
    }

    fn table(c: &Candidate, values: &[f64]) -> toml::Table {
        let mut t: toml::Table = toml::from_str(c.fixed).unwrap();
        t.insert("kind".into(), toml::Value::String(c.kind.into()));
        for (p, v) in c.params.iter().zip(values) {
            t.insert(p.name.into(), toml::Value::Float(*v));
        }
        t
    }

    /// The VE change of `c` at `values` under `vib`/`psd`, as the lab evaluates it.
    fn shift(
        c: &Candidate,
        values: &[f64],
        vib: &Vibration,
        psd: &[PsdBand],
    ) -> vibro_effects::Result<f64> {
        let p = al15();
        let e = build_effects(&[table(c, values)], &p).unwrap();
        if sensor_rms_factor(&e, &p, [0.0, 0.0, 1.0], vib, psd) != 1.0 {
            // A sensor effect rescales the vibration the model sees: no mean formula.
            return Ok(0.0);
        }
        Ok(effect_shifts_g(&e, &p, [0.0, 0.0, 1.0], vib, psd, 10.0)?
            .iter()
            .map(|(_, s)| s)
            .sum())
    }

    #[test]
    fn every_effect_of_the_simulator_is_a_candidate() {
        let mut want: Vec<&str> = vibro_effects::catalogue().iter().map(|i| i.kind).collect();
        let mut have = kinds();
        want.sort_unstable();
        have.sort_unstable();
        assert_eq!(have, want);
    }

    /// `needs_spectrum` is exactly the candidates whose mean formula fails on a random
    /// part without a spectrum (all three axes random, IA correlated with OA and PA);
    /// given a flat band every candidate evaluates.
    #[test]
    fn needs_spectrum_marks_the_formulas_that_fail_without_one() {
        let mut vib = Vibration::random_rms([1.0, 1.0, 1.0]);
        for j in 0..2 {
            vib.covariance_g2[2][j] = 0.5;
            vib.covariance_g2[j][2] = 0.5;
        }
        let band = [PsdBand {
            f_lo_hz: 20.0,
            f_hi_hz: 2000.0,
            psd_g2_per_hz: [1.0 / 1980.0; 3],
        }];
        for c in LIBRARY {
            let values: Vec<f64> = c.params.iter().map(representative).collect();
            let without = shift(c, &values, &vib, &[]);
            assert_eq!(
                without.is_err(),
                c.needs_spectrum,
                "{}: {without:?}",
                c.kind
            );
            let with = shift(c, &values, &vib, &band);
            assert!(
                with.as_ref().is_ok_and(|s| s.is_finite()),
                "{}: {with:?}",
                c.kind
            );
        }
    }

    /// `acts_on_inputs` is exactly the effects on the vibration path
    /// (`Effect::on_vibration_path`) and those of the vibration sensor (`at_sensor`).
    #[test]
    fn acts_on_inputs_marks_the_path_and_sensor_effects() {
        let p = al15();
        for c in LIBRARY {
            let values: Vec<f64> = c.params.iter().map(representative).collect();
            let e = build_effects(&[table(c, &values)], &p).unwrap();
            let info = vibro_effects::catalogue()
                .iter()
                .find(|i| i.kind == c.kind)
                .unwrap();
            let path = e.iter().any(|e| e.on_vibration_path()) || info.hooks.contains("at_sensor");
            assert_eq!(c.acts_on_inputs, path, "{}", c.kind);
        }
    }

    /// Every bound and every start lies within the effect's own validation range: the
    /// effect builds there.
    #[test]
    fn bounds_and_starts_are_valid_parameters_of_the_effect() {
        let p = al15();
        for c in LIBRARY {
            let base: Vec<f64> = c.params.iter().map(representative).collect();
            for (k, spec) in c.params.iter().enumerate() {
                let mut xs = vec![spec.bounds.0, spec.bounds.1];
                if let Search::Grid(g) = spec.search {
                    xs.extend_from_slice(g);
                }
                for x in xs {
                    assert!(
                        (spec.bounds.0..=spec.bounds.1).contains(&x),
                        "{}.{} start {x} outside {:?}",
                        c.kind,
                        spec.name,
                        spec.bounds
                    );
                    let mut v = base.clone();
                    v[k] = x;
                    let built = build_effects(&[table(c, &v)], &p);
                    assert!(
                        built.is_ok(),
                        "{}.{} = {x}: {:?}",
                        c.kind,
                        spec.name,
                        built.err()
                    );
                }
            }
        }
    }
}
