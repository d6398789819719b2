//! # vibro-waveform
//!
//! Compensation from the waveform, MODEL.md section 12 (beyond the papers). A reading
//! `R_n = U_n / K1` is the mean of the conversion function (FP) over its own interval
//! `I_n = (t_n - T, t_n]` under the vibration that actually happened; the vibration
//! sensors record that vibration. Per reading and unit:
//!
//! 1. the sensors' samples with their chain undone ([`chain`]: sensitivity, the AC
//!    coupling's high-pass inverted, the stated delay taken off the time stamps);
//! 2. interpolated band-limited ([`kernel`]: a Kaiser-windowed sinc) onto a grid of
//!    `M + 1` points per reading, its ends on the interval's (at least the sensor rate
//!    and 25.6 kHz, so that FP's fifth power of the vibration is resolved), and averaged
//!    by Gregory's end-corrected rule (section 12's quadrature);
//! 3. mapped from the sensors (each along its unit's IA) to the body frame and to each
//!    unit's `[OA, PA, IA]` (`TriadAxes`, as `vibro_effects::mapping` maps estimates);
//! 4. through the model's path effects (`Effect::at_unit_input`: mount, the unit's own
//!    response, axis phase), run on the fine grid with their state kept from reading to
//!    reading;
//! 5. split into the interval mean and the deviation `d(t)`; the mean `m` of each unit
//!    is solved by Newton from `F(m) = mean FP(m + d) + output effects = R`, the three
//!    units together (their OA and PA means are the other units' IA means).
//!
//! The result is the interval-mean acceleration each unit sensed: main and vibration
//! error removed in one step, with no expectation taken ([`stage::WaveformStage`]).
//!
//! Departures, written down:
//!
//! - Output effects (`Effect::at_unit_output`: vibropendulous, heating, k6/k7, clips)
//!   are stateful filters, so they run once per fine point, at the previous
//!   reading's solution carried forward (the guess); their contribution is then held
//!   fixed while Newton solves FP. The error is their slope times the guess's error,
//!   about 1e-4 x 1e-5 g: below 1e-9 g.
//! - Sensor-side effects (`Effect::at_sensor`, a sensor's gain or misalignment) are not
//!   undone: the sensors' chain is what the configuration states.
//! - `lambda(w)` of the passport is 1 here, as in the simulator's FP (a unit's own
//!   frequency response is a path effect, `unit_response`).

// Per-unit and per-axis index loops mirror the formulas' subscripts (and index several
// arrays at once).
#![allow(clippy::needless_range_loop)]

pub mod chain;
pub mod kernel;
pub mod stage;

pub use chain::{ChainProblem, SensorChain};
pub use stage::{Coverage, StageCounters, VibPush, WaveformError, WaveformStage};
