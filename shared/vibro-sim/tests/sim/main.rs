//! Integration tests of the simulator, one module per topic. Every check compares the
//! simulated signal with an independent reference: the exact model of vibro-physics,
//! the PSD table, a formula, another library (vibro-dsp, vibro-ident) or another run.

mod campaign_ve;
mod common;
mod compensation;
mod determinism;
mod effects;
mod flight;
mod positions;
mod random_vibration;
mod scenarios;
mod sensor;
mod timing;
