//! `heating`: the unit warms up under vibration and its bias drifts (MODEL.md section
//! 11, eighth item).
//!
//! Physics: vibration dissipates energy in the unit (damping fluid, suspension,
//! servo), and its temperature, hence its bias, follows the dissipated power through
//! the unit's thermal lag. Model: a bias `b(t)` with `tau db/dt = c v3(t)^2 - b`,
//! `b(0) = 0` (cold at the start of the run), where `v3^2` is the vibration power along
//! IA and `c = c_g_per_g2` the bias per g^2 at thermal equilibrium. Hooks:
//! [`Effect::at_unit_input`] measures each block's mean `v3^2` (the vibration part
//! there, as the unit receives it) and [`Effect::at_unit_output`] adds, at every
//! sample, the mean of `b` over that sample's interval from the exact solution of the
//! lag under the block's mean power (a block is far shorter than any thermal time
//! constant, so feeding the lag with the block mean instead of sample by sample
//! changes nothing of interest, and the time average of the added bias equals the
//! integral of the continuous `b`).
//!
//! Mean contribution over a run of duration `T` (`MeanContext::duration_s`) starting
//! cold at t = 0: with `P = E[v3^2] = sum_tones aB3^2/2 + sigma3^2` (MODEL.md section
//! 6), `b(t) = c P (1 - e^{-t/tau})` in expectation and its time average is
//! `c P (1 - tau/T (1 - e^{-T/tau}))`.

use super::{EffectInfo, ParamInfo, Params, Scope};
use crate::effect::{BlockCtx, Effect, MeanContext, OutputTerms};
use crate::{Error, Result};

const KIND: &str = "heating";

/// Catalogue entry.
pub const INFO: EffectInfo = EffectInfo {
    kind: KIND,
    summary: "bias drift from heating under vibration: first-order thermal lag driven by the \
              IA vibration power, starting cold",
    params: &[
        ParamInfo {
            name: "c_g_per_g2",
            unit: "g/g^2",
            meaning: "equilibrium bias per g^2 of IA vibration power; required, |c| <= 0.1",
        },
        ParamInfo {
            name: "tau_s",
            unit: "s",
            meaning: "thermal time constant; required, 0 < tau <= 1e6",
        },
    ],
    hooks: "at_unit_input (power), at_unit_output (bias)",
    scope: Scope::Unit,
    example: r#"[[effect]]
kind = "heating"
c_g_per_g2 = 2.0e-6
tau_s = 120.0
"#,
    build,
};

fn build(p: &mut Params<'_>) -> Result<Box<dyn Effect>> {
    let c_g_per_g2 = p.required("c_g_per_g2", "must be finite and |c| <= 0.1 g/g^2", |c| {
        c.abs() <= 0.1
    });
    let tau_s = p.required("tau_s", "must be finite and 0 < tau_s <= 1e6 s", |t| {
        t > 0.0 && t <= 1e6
    });
    Ok(Box::new(Heating {
        c_g_per_g2,
        tau_s,
        bias_g: [0.0; 3],
        block_power_g2: [0.0; 3],
    }))
}

#[derive(Debug, Clone)]
struct Heating {
    c_g_per_g2: f64,
    tau_s: f64,
    /// Per unit: the bias at the start of the next sample.
    bias_g: [f64; 3],
    /// Per unit: the mean `v3^2` of the block last seen by `at_unit_input`.
    block_power_g2: [f64; 3],
}

impl Effect for Heating {
    fn kind(&self) -> &'static str {
        KIND
    }

    fn reset(&mut self, _internal_rate_hz: f64) {
        self.bias_g = [0.0; 3];
        self.block_power_g2 = [0.0; 3];
    }

    fn at_unit_input(&mut self, ctx: &BlockCtx, vib_unit_g: &mut [[f64; 3]]) {
        let Some(power) = self.block_power_g2.get_mut(ctx.unit) else {
            return;
        };
        if vib_unit_g.is_empty() {
            return;
        }
        let sum: f64 = vib_unit_g.iter().map(|v| v[2] * v[2]).sum();
        *power = sum / vib_unit_g.len() as f64;
    }

    fn at_unit_output(&mut self, ctx: &BlockCtx, _input_unit_g: &[[f64; 3]], out_g: &mut [f64]) {
        let (Some(bias), Some(power)) = (
            self.bias_g.get_mut(ctx.unit),
            self.block_power_g2.get(ctx.unit),
        ) else {
            return;
        };
        let target = self.c_g_per_g2 * power;
        let h = ctx.dt_s / self.tau_s;
        // Exact lag over one sample: b(t+dt) = target + (b - target) e^{-h}; its mean
        // over the interval is target + (b - target) (1 - e^{-h})/h.
        let decay = (-h).exp();
        let mean_factor = if h > 1e-12 { -(-h).exp_m1() / h } else { 1.0 };
        for o in out_g.iter_mut() {
            *o += target + (*bias - target) * mean_factor;
            *bias = target + (*bias - target) * decay;
        }
    }

    fn mean_shift_g(&self, ctx: &MeanContext<'_>) -> Result<f64> {
        let t = ctx.duration_s;
        if !(t.is_finite() && t > 0.0) {
            return Err(Error::Invalid {
                key: format!("effect[{KIND}]"),
                value: format!("duration_s = {t}"),
                rule: "the mean over a run needs a finite run duration > 0 s".into(),
            });
        }
        let vib = ctx.vibration_unit;
        let power: f64 = vib
            .tones()
            .iter()
            .map(|t| 0.5 * t.amplitude_g[2] * t.amplitude_g[2])
            .sum::<f64>()
            + vib.covariance_g2[2][2];
        let x = t / self.tau_s;
        // 1 - (1 - e^{-x})/x, written with exp_m1 for long and short runs alike.
        let warm_fraction = 1.0 + (-x).exp_m1() / x;
        Ok(self.c_g_per_g2 * power * warm_fraction)
    }

    /// The bias as a constant at its mean over the run (its slow rise inside a clip
    /// changes the clipped mean by about its variance over the run times the output
    /// density at the range: negligible for a time constant short against the run).
    fn output_terms(&self, ctx: &MeanContext<'_>) -> Option<OutputTerms> {
        self.mean_shift_g(ctx).ok().map(|bias_g| OutputTerms {
            bias_g,
            ..OutputTerms::default()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::testkit::{al15, assert_agrees, band, build_toml, tone, unit_shift, Scene};

    /// An 8 s run with a 2 s thermal lag from cold: the warm-up is a quarter of the
    /// mean. Blocks of 1000 samples at 2048 Hz.
    #[test]
    fn mean_formula_matches_time_domain() {
        let p = al15();
        let mut s = Scene::new(2048.0, 1 << 14);
        s.a_l_g = [0.0, 0.0, 1.0];
        s.tones = vec![tone(30.3, [1.0, 1.0, 1.4], [0.0; 3])];
        s.bands = vec![band(20.0, 400.0, [0.004, 0.004, 0.004])];
        let mut e = build_toml("kind = \"heating\"\nc_g_per_g2 = 1e-4\ntau_s = 2.0", &p);
        let vib = s.vibration();
        let formula = e.mean_shift_g(&s.ctx(2, &p, &vib)).unwrap();
        let est = unit_shift(&s, &p, 2, e.as_mut(), 1200);
        assert_agrees("heating", est, formula, 10.0);
    }

    #[test]
    fn a_long_run_reaches_equilibrium_and_a_short_one_stays_cold() {
        let p = al15();
        let e = build_toml("kind = \"heating\"\nc_g_per_g2 = 1e-4\ntau_s = 2.0", &p);
        let vib = vibro_physics::vibration::Vibration::random_rms([0.0, 0.0, 2.0]);
        let mut s = Scene::new(1000.0, 1 << 10);
        let mut ctx_at = |n: usize| {
            s.n = n;
            let c = s.clone();
            e.mean_shift_g(&c.ctx(0, &p, &vib)).unwrap()
        };
        assert!((ctx_at(1 << 30) - 4e-4).abs() < 1e-8);
        assert!(ctx_at(1) < 1e-6);
    }
}
