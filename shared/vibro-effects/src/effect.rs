//! The contract between the simulator and its physical effects.
//!
//! The simulator runs one chain per accelerometer unit (MODEL.md section 2 frames:
//! index 0 = OA (axis 1), 1 = PA (axis 2), 2 = IA (axis 3)):
//!
//! ```text
//!  scenario vibration (body frame, a `Vibration` description + PSD bands)
//!     |  Effect::adjust_body_vibration      (generation side: phases, kurtosis, ...)
//!     v
//!  body-frame vibration samples at the internal rate
//!     |---------------------------------------------> vibration sensor of unit u
//!     |                                                 Effect::at_sensor (gain, misalignment)
//!     |                                                 then sensitivity, AC coupling, noise, ADC
//!     |  rotate to unit u's axes [OA, PA, IA]
//!     |  Effect::at_unit_input  (vibration part only: mount transmissibility,
//!     |                          the unit's own frequency response, clipping of the input)
//!     v
//!  a_unit = aL_unit + vibration_unit
//!     |  conversion function (FP) of the passport, per sample
//!     |  Effect::at_unit_output (terms the FP lacks: vibropendulous, anisoelastic,
//!     |                          k6/k7, heating, frequency-dependent scale factor)
//!     v
//!  instantaneous output aF (g), averaged to the output rate
//! ```
//!
//! Every effect documents its mean contribution in [`Effect::mean_shift_g`]: the
//! change of the unit's time-averaged output that switching the effect on (alone)
//! causes, from a formula that does not run the time-domain simulation. Tests check
//! the simulator against it.
//!
//! Hooks are called once per block of samples with buffers the simulator owns; an
//! effect keeps its filter state between blocks, allocates only in its constructor
//! or in [`Effect::reset`], and never logs per sample.

use realfft::num_complex::Complex;
use vibro_physics::passport::Passport;
use vibro_physics::vibration::{PsdBand, Vibration};

/// Where a block of samples sits in the run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BlockCtx {
    /// Unit index in the triad, 0..3.
    pub unit: usize,
    /// Time of the block's first sample since the start of the run, s.
    pub t0_s: f64,
    /// Sample period of the internal rate, s.
    pub dt_s: f64,
}

/// What a mean-contribution formula may use: the unit's passport, its steady flight
/// acceleration and the vibration at the unit as the scenario describes it (before
/// any effect), in the unit's axes.
#[derive(Debug, Clone, Copy)]
pub struct MeanContext<'a> {
    pub unit: usize,
    pub passport: &'a Passport,
    /// Flight (slow) acceleration in the unit's axes `[aL1, aL2, aL3]`, g.
    pub a_l_unit_g: [f64; 3],
    /// Vibration at the unit in its axes, with the effect switched off.
    pub vibration_unit: &'a Vibration,
    /// The random part's band PSD in the unit's axes (empty when the scenario gives
    /// the random vibration as an RMS only). Sums to `vibration_unit.covariance_g2`'s
    /// diagonal.
    pub psd_unit: &'a [PsdBand],
    /// Internal sample rate of the simulation, Hz (for effects whose discrete-time
    /// realisation matters, such as a digital filter's exact response).
    pub internal_rate_hz: f64,
    /// Duration of the averaged run, s (for effects with a time constant).
    pub duration_s: f64,
}

/// Output terms that are memoryless functions of the unit's total acceleration (or
/// constant over a run), `bias + c12 a1 a2 + k6 a3^6 + k7 a3^7`, g, and a product
/// `h a2` with `h` a linear filter of the IA acceleration (the vibropendulous term
/// `c HP[a3] a2`): what an effect that clips the whole output
/// ([`Effect::mean_shift_over_g`]) must clip with the FP.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct OutputTerms {
    /// Constant over the run, g.
    pub bias_g: f64,
    /// Coefficient of `a1 a2` (OA x PA), 1/g.
    pub a1_a2_per_g: f64,
    /// Coefficient of `a3^6`, 1/g^5.
    pub a3_pow6_per_g5: f64,
    /// Coefficient of `a3^7`, 1/g^6.
    pub a3_pow7_per_g6: f64,
    /// `h = sum_k Re(G_k e^(j (theta_k + phi3_k))) ...`: per tone of the context's
    /// vibration (in its order), the complex gain `G_k` (1/g) from the tone's IA part
    /// to `h` (for `c HP[a3] a2`: `c HP(f_k)`), so that a tone adds
    /// `A3_k |G_k| sin(theta_k + phi3_k + arg G_k)` to `h`.
    pub ia_filter_tone_gain: [(f64, f64); vibro_physics::vibration::MAX_TONES],
    /// The random part's `h` per unit of the IA random acceleration (its regression:
    /// `cov(h, x3) / sigma3^2`), 1/g.
    pub ia_filter_random_gain: f64,
}

impl OutputTerms {
    /// The terms at the total acceleration `a_g` (unit axes) and the filtered IA
    /// acceleration `h` there, g.
    #[inline]
    pub fn at(&self, a_g: [f64; 3], h: f64) -> f64 {
        let a3_6 = a_g[2].powi(6);
        self.bias_g
            + self.a1_a2_per_g * a_g[0] * a_g[1]
            + a3_6 * (self.a3_pow6_per_g5 + self.a3_pow7_per_g6 * a_g[2])
            + h * a_g[1]
    }

    /// Whether an IA filter term (`h a2`) is present.
    pub fn has_ia_filter(&self) -> bool {
        self.ia_filter_random_gain != 0.0
            || self
                .ia_filter_tone_gain
                .iter()
                .any(|g| g.0 != 0.0 || g.1 != 0.0)
    }

    /// An upper bound of `|terms|` over `|a_i| <= reach_g[i]` and `|h| <= h_reach`.
    pub fn bound_g(&self, reach_g: [f64; 3], h_reach: f64) -> f64 {
        let a3_6 = reach_g[2].powi(6);
        self.bias_g.abs()
            + self.a1_a2_per_g.abs() * reach_g[0] * reach_g[1]
            + a3_6 * (self.a3_pow6_per_g5.abs() + self.a3_pow7_per_g6.abs() * reach_g[2])
            + h_reach * reach_g[1]
    }

    /// The sum of two sets of terms.
    pub fn plus(self, o: Self) -> Self {
        Self {
            bias_g: self.bias_g + o.bias_g,
            a1_a2_per_g: self.a1_a2_per_g + o.a1_a2_per_g,
            a3_pow6_per_g5: self.a3_pow6_per_g5 + o.a3_pow6_per_g5,
            a3_pow7_per_g6: self.a3_pow7_per_g6 + o.a3_pow7_per_g6,
            ia_filter_tone_gain: std::array::from_fn(|k| {
                (
                    self.ia_filter_tone_gain[k].0 + o.ia_filter_tone_gain[k].0,
                    self.ia_filter_tone_gain[k].1 + o.ia_filter_tone_gain[k].1,
                )
            }),
            ia_filter_random_gain: self.ia_filter_random_gain + o.ia_filter_random_gain,
        }
    }
}

/// One physical effect the conversion function (FP) of MODEL.md leaves out
/// (MODEL.md section 11). Every hook defaults to "no change".
pub trait Effect: Send {
    /// The effect's name in scenarios (`kind = "..."`) and reports.
    fn kind(&self) -> &'static str;

    /// Generation side: adjust the body-frame vibration description before samples
    /// are drawn (phase between axes, kurtosis of the random part, ...).
    fn adjust_body_vibration(&self, _vib_body: &mut Vibration) {}

    /// Clear filter state and size buffers for a run at `internal_rate_hz`.
    fn reset(&mut self, _internal_rate_hz: f64) {}

    /// The vibration-sensor reading of unit `ctx.unit` before the sensor's own
    /// electronics: `body_vib_g` are the body-frame vibration samples, `sensor_g`
    /// holds the ideal reading (the vibration along the unit's IA) and may be changed.
    fn at_sensor(&mut self, _ctx: &BlockCtx, _body_vib_g: &[[f64; 3]], _sensor_g: &mut [f64]) {}

    /// The vibration reaching the accelerometer, in its axes `[OA, PA, IA]`, g
    /// (vibration part only, without the flight acceleration); may be changed in place.
    fn at_unit_input(&mut self, _ctx: &BlockCtx, _vib_unit_g: &mut [[f64; 3]]) {}

    /// Terms added to the instantaneous output: `input_unit_g` is the total
    /// acceleration at the unit (flight + vibration, after `at_unit_input`),
    /// `out_g` the FP output in g, to which the effect adds.
    fn at_unit_output(&mut self, _ctx: &BlockCtx, _input_unit_g: &[[f64; 3]], _out_g: &mut [f64]) {}

    /// The documented mean contribution: the change of the unit's mean output, g,
    /// when this effect alone is switched on, evaluated from a formula (closed form
    /// or deterministic quadrature over the exact distributions), never from the
    /// time-domain simulation.
    fn mean_shift_g(&self, ctx: &MeanContext<'_>) -> crate::Result<f64>;

    /// For effects acting only on the vibration sensors: the factor by which the
    /// sensor's measured RMS (per tone amplitude and per band RMS) along IA changes,
    /// `None` for other effects.
    fn sensor_rms_factor(&self, _ctx: &MeanContext<'_>) -> Option<f64> {
        None
    }

    /// Whether the effect changes the vibration reaching the unit (`at_unit_input`
    /// filters such as a mount resonance), so that every effect after it in the
    /// unit's path sees its output ([`Effect::transmitted`]).
    fn on_vibration_path(&self) -> bool {
        false
    }

    /// For effects whose output term is memoryless in the unit's total acceleration
    /// (or constant over the run): that term under `ctx` (the effect switched on).
    /// `None` for others (filters, clips, sensor effects).
    fn output_terms(&self, _ctx: &MeanContext<'_>) -> Option<OutputTerms> {
        None
    }

    /// The frequency-domain form of a linear, time-invariant vibration-path effect
    /// ([`Effect::at_unit_input`]): the transfer `H(j 2 pi f)` of the continuous-time
    /// system on each of unit `unit`'s axes `[OA, PA, IA]`, of which the hook runs the
    /// discretisation (a biquad at the internal rate). The lab's fit to a log's readings
    /// filters whole records in the frequency domain with it (`vibro_wavefit`): exact
    /// for any rate, and cheap to differentiate. `None` for effects that are not LTI
    /// path filters; `Some([1; 3])` on a unit the effect does not act on.
    fn path_transfer(&self, _unit: usize, _f_hz: f64) -> Option<[Complex<f64>; 3]> {
        None
    }

    /// For effects on a vibration sensor's reading ([`Effect::at_sensor`]) that are
    /// linear in the vibration: the sensor of unit `unit` reads
    /// `c[0] v_OA + c[1] v_PA + c[2] v_IA` (the unit's axes), `c` returned. `None` for
    /// other effects; `Some([0, 0, 1])` on a unit it does not act on.
    fn sensor_response(&self, _unit: usize) -> Option<[f64; 3]> {
        None
    }

    /// Whether the effect acts on the whole output (a clip), so that its mean depends
    /// on the other effects' output terms ([`Effect::mean_shift_over_g`]).
    fn clips_output(&self) -> bool {
        false
    }

    /// For effects that act on the whole output (a clip): the mean change when the
    /// output already carries `others`, the memoryless terms of the unit's other
    /// effects ([`Effect::output_terms`]). `None` for effects that only add to the
    /// output.
    fn mean_shift_over_g(
        &self,
        _ctx: &MeanContext<'_>,
        _others: &OutputTerms,
    ) -> Option<crate::Result<f64>> {
        None
    }

    /// For effects on the vibration path: the vibration and its band PSD reaching the
    /// unit when `ctx.vibration_unit` and `ctx.psd_unit` reach the effect (the mean
    /// formula's own view of `at_unit_input`). `None` for other effects.
    fn transmitted(
        &self,
        _ctx: &MeanContext<'_>,
    ) -> Option<crate::Result<(Vibration, Vec<PsdBand>)>> {
        None
    }
}
