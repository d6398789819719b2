//! # vibro-sim
//!
//! The rig simulator: it makes, in the time domain, the streams a real rig would give
//! the rest of vibrocomp (the vibration sensors at 25.6 kHz, the accelerometers'
//! mean outputs at the navigation rate) together with the truth, so that the
//! vibration error (VE) of MODEL.md *emerges from the signal* (the conversion
//! function (FP) applied sample by sample and averaged) instead of being taken from
//! the closed forms it is then checked against. Physical effects the model lacks
//! (MODEL.md section 11) plug in through the `vibro_effects::Effect` contract (the
//! effects library, `vibro-effects`).
//!
//! A [`Scenario`] (`config/scenarios/*.toml`, [`scenario`]) is either
//!
//! - a **flight** of the triad of RIG.md: a piecewise-linear flight acceleration in body
//!   axes, tones (optionally swept) and band-shaped random vibration (optionally
//!   cross-correlated and non-Gaussian); run it as a stream with [`Simulator`]; or
//! - a shake-table **campaign** on one unit: a grid of conditions (orientation, vibration
//!   direction, tone or PSD), each still / vibrating / still and measured as MODEL.md
//!   section 8 does; run it with [`run_campaign`], write [`write_summary_csv`] (and, for
//!   test positions, [`write_positions_csv`], which `vibrocomp identify positions` reads).
//!
//! Per run, at the internal rate (MODEL.md frames: unit axes `[OA, PA, IA]`):
//!
//! ```text
//! tones (phase = integral of f) + random (white -> Cholesky(coherence) -> FIR -> sqrt(w) per segment)
//!   = body vibration (Effect::adjust_body_vibration acts on its description first)
//!   |-- unit u's IA --> Effect::at_sensor --> sensitivity, AC coupling, noise, ADC  => sensor_v[u]
//!   |-- rotate to [OA, PA, IA] --> Effect::at_unit_input
//!   + flight acceleration --> FP (vibro_physics::fp, lambda = 1) --> Effect::at_unit_output
//!   --> mean over each output interval, times K1                                     => accel_v[u]
//! truth per output sample: mean flight acceleration, exact E[aF] and VE (vibro_physics::exact)
//! ```
//!
//! Every source of randomness has its own ChaCha8 stream (tone phases, noise per axis,
//! mixture segments, sensor noise), so the same scenario and seed give bit-identical
//! output, whatever the chunk size, and switching an effect on leaves the other draws
//! unchanged (common random numbers).
//!
//! ```
//! use std::ops::ControlFlow;
//! let text = r#"
//!     name = "doc"
//!     seed = 1
//!     [rates]
//!     output_hz = 800
//!     [sensor]
//!     sensitivity_v_per_g = 0.1
//!     ac_corner_hz = 0.5
//!     noise_g_rms = 1e-3
//!     adc_bits = 24
//!     full_scale_v = 10.0
//!     [flight]
//!     duration_s = 0.5
//!     triad = "default"
//!     [[flight.profile]]
//!     t_s = 0.0
//!     accel_body_g = [2.0, 0.0, 0.0]
//!     [[flight.tone]]
//!     freq_hz = 30.0
//!     amplitude_g = [2.0, 0.0, 0.0]
//! "#;
//! let scenario = vibro_sim::parse_scenario(text, "doc.toml", None)?;
//! let mut sim = vibro_sim::Simulator::new(&scenario, Vec::new())?;
//! let (mut sum_v, mut n) = (0.0, 0);
//! sim.run(|chunk| {
//!     for row in chunk.accel_v() {
//!         sum_v += row[0];
//!         n += 1;
//!     }
//!     ControlFlow::Continue(())
//! })?;
//! // AK1 (IA = +x, AL-15, K1 = -1.6698 V/g) reads about 2 g plus its errors.
//! let mean_g = sum_v / n as f64 / -1.6698;
//! assert_eq!(n, 400);
//! assert!((mean_g - 2.0).abs() < 0.01, "{mean_g}");
//! # Ok::<(), vibro_sim::Error>(())
//! ```
//!
//! References: MODEL.md (sections 2-8; equation numbers `[P1 (n)]`, `[P2 (n)]` are the
//! papers'), RIG.md (rigs, flights, environments); P. D. Welch (1967) for the spectral
//! checks in the tests; A. V. Oppenheim, R. W. Schafer, *Discrete-Time Signal
//! Processing*, 3rd ed., 2010, sections 7.2 (bilinear transform with pre-warping, the
//! sensor's AC coupling) and 8.7 (overlap-save block convolution, the random
//! vibration's FIR).

// Index loops mirror the formulas' subscripts (axis i, K_ij, L_ij) and index several
// arrays at once; iterator chains would hide the indices (as in vibro-physics).
#![allow(clippy::needless_range_loop)]

pub mod campaign;
pub mod campaign_report;
mod engine;
mod error;
pub mod flight_stats;
pub mod overrides;
pub mod random;
pub mod scenario;
pub mod sensor;
mod streams;
mod tones;

pub use campaign::{
    run_campaign, run_condition, run_condition_records, write_positions_csv, write_summary_csv,
    CampaignOptions, ConditionRun, ConditionSummary, EffectShift, MeasuredVibration,
};
pub use campaign_report::{CampaignReport, ConditionReport};
pub use engine::{scenario_effects, SampleCounts, SimChunk, Simulator, Truth, DEFAULT_CHUNK_S};
pub use error::{Error, Result};
pub use flight_stats::{FlightStats, UnitReport};
pub use overrides::{apply_overrides, effect_labels, parse_effect, Overrides};
pub use scenario::{load_scenario, parse_scenario, resolve_scenario, Scenario, ScenarioKind};
pub use tones::Sweep;
