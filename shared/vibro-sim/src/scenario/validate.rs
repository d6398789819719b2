//! Validation: a [`ScenarioRaw`] checked rule by rule into a [`Scenario`], every
//! problem collected and reported at once, each naming the key path, the value and
//! the rule.

use super::checks::{
    check_kurtosis, check_tone_freq, merge_axes, psd3_shape, random_numerics, Problems,
};
use super::grid::expand_grid;
use super::raw::{CampaignRaw, FlightRaw, RandomRaw, RatesRaw, ScenarioRaw, SensorRaw};
use super::types::{
    Campaign, Flight, FlightTone, Profile, RandomSpec, Rates, Scenario, ScenarioKind, SensorSpec,
};
use super::{campaign_axes, Refs, DEFAULT_BATCHES, DEFAULT_SENSOR_RATE_HZ, DEFAULT_TILT_LIMIT_RAD};
use crate::random::{cholesky_residual, RandomSetup};
use crate::{Error, Result};
use std::path::Path;
use vibro_effects::{build_for_rig, Rig};
use vibro_physics::vibration::{Tone, MAX_TONES};

/// Whether `x` is within `1e-9` (relative) of a whole number >= 1.
fn whole(x: f64) -> Option<u64> {
    if !(x.is_finite() && (0.5..9e15).contains(&x)) {
        return None;
    }
    let r = x.round();
    ((x - r).abs() <= 1e-9 * r.max(1.0)).then_some(r as u64)
}

impl TryFrom<ScenarioRaw> for Scenario {
    type Error = Error;

    /// Validates a scenario built in code (file references relative to the working
    /// directory); see [`Scenario::try_from_raw`].
    fn try_from(raw: ScenarioRaw) -> Result<Self> {
        Scenario::try_from_raw(raw, "<scenario>", None)
    }
}

impl Scenario {
    /// Checks every rule of `raw`, reporting all problems at once.
    pub fn try_from_raw(raw: ScenarioRaw, file: &str, base_dir: Option<&Path>) -> Result<Self> {
        let refs = Refs { base_dir };
        let mut p = Problems::default();
        // Sizes first: a value over its bound is not looked at further.
        if !super::sizes::check_sizes(&raw, &mut p.0) {
            return Err(Error::Scenario {
                file: file.to_string(),
                problems: p.0,
            });
        }
        if raw.name.trim().is_empty() {
            p.push("name", format!("{:?}", raw.name), "must not be empty");
        }
        let rates = validate_rates(&raw.rates, &mut p);
        let sensor = validate_sensor(&raw.sensor, rates.sensor_hz, &mut p);
        let kind = match (&raw.flight, &raw.campaign) {
            (Some(f), None) => {
                validate_flight(f, &rates, &refs, &mut p).map(|f| ScenarioKind::Flight(Box::new(f)))
            }
            (None, Some(c)) => validate_campaign(c, &rates, &refs, &mut p)
                .map(|c| ScenarioKind::Campaign(Box::new(c))),
            (Some(_), Some(_)) => {
                p.note("[flight] and [campaign]: a scenario is one or the other, not both".into());
                None
            }
            (None, None) => {
                p.note("missing [flight] or [campaign]: a scenario needs one of them".into());
                None
            }
        };
        // Every effect is built once (enabled or not) so that its parameters are
        // checked now, not mid-run.
        if let Some(kind) = &kind {
            let rig = match kind {
                ScenarioKind::Flight(f) => Rig {
                    triad: f.triad.axes,
                    passports: Some(f.triad.passports),
                },
                ScenarioKind::Campaign(c) => Rig {
                    triad: campaign_axes(),
                    passports: Some([c.passport; 3]),
                },
            };
            for (i, spec) in raw.effect.iter().enumerate() {
                if let Err(e) = build_for_rig(spec, &rig) {
                    p.note(format!("effect[{i}] (kind = {:?}): {e}", spec.kind));
                }
                if matches!(kind, ScenarioKind::Campaign(_)) {
                    if let Some(units) = &spec.units {
                        if units.iter().any(|u| *u != 0) {
                            p.push(
                                format!("effect[{i}].units"),
                                format!("{units:?}"),
                                "a campaign has one unit under test: only unit 0",
                            );
                        }
                    }
                }
            }
        }
        match kind {
            Some(kind) if p.0.is_empty() => Ok(Scenario {
                name: raw.name,
                description: raw.description.unwrap_or_default(),
                file: file.to_string(),
                seed: raw.seed,
                rates,
                sensor,
                effects: raw.effect,
                kind,
            }),
            _ => Err(Error::Scenario {
                file: file.to_string(),
                problems: p.0,
            }),
        }
    }
}

fn validate_rates(r: &RatesRaw, p: &mut Problems) -> Rates {
    let sensor_hz = r.sensor_hz.unwrap_or(DEFAULT_SENSOR_RATE_HZ);
    let sensor_ok = whole(sensor_hz).is_some() && (100.0..=1e6).contains(&sensor_hz);
    if !sensor_ok {
        p.push(
            "rates.sensor_hz",
            sensor_hz,
            "must be a whole number of Hz within 100..=1e6",
        );
    }
    let internal_hz = r.internal_hz.unwrap_or(sensor_hz);
    match whole(internal_hz / sensor_hz) {
        Some(m) if (1..=64).contains(&m) && sensor_ok => {}
        _ => p.push(
            "rates.internal_hz",
            internal_hz,
            format!("must be the sensor rate {sensor_hz} Hz times a whole number 1..=64"),
        ),
    }
    let output_ok = r.output_hz.is_finite() && r.output_hz > 0.0;
    match whole(internal_hz / r.output_hz) {
        Some(_) if output_ok => {}
        _ => p.push(
            "rates.output_hz",
            r.output_hz,
            format!(
                "must divide the internal rate {internal_hz} Hz a whole number of times \
                 (the output is the mean over whole internal samples)"
            ),
        ),
    }
    Rates {
        sensor_hz,
        internal_hz,
        output_hz: r.output_hz,
    }
}

fn validate_sensor(s: &SensorRaw, sensor_hz: f64, p: &mut Problems) -> SensorSpec {
    let k = "sensor";
    let sens = s.sensitivity_v_per_g;
    if !(sens.is_finite() && (1e-6..=1e3).contains(&sens.abs())) {
        p.push(
            format!("{k}.sensitivity_v_per_g"),
            sens,
            "must be finite with 1e-6 <= |sensitivity| <= 1e3 V/g",
        );
    }
    if !(s.ac_corner_hz.is_finite() && s.ac_corner_hz >= 0.0 && s.ac_corner_hz < sensor_hz / 4.0) {
        p.push(
            format!("{k}.ac_corner_hz"),
            s.ac_corner_hz,
            format!("must be finite, >= 0 (0: DC-coupled) and below a quarter of the sensor rate, {} Hz", sensor_hz / 4.0),
        );
    }
    if !(s.noise_g_rms.is_finite() && (0.0..=1e3).contains(&s.noise_g_rms)) {
        p.push(
            format!("{k}.noise_g_rms"),
            s.noise_g_rms,
            "must be finite and 0 <= noise <= 1000 g RMS",
        );
    }
    if !(2..=32).contains(&s.adc_bits) {
        p.push(format!("{k}.adc_bits"), s.adc_bits, "must be 2..=32 bits");
    }
    if !(s.full_scale_v.is_finite() && s.full_scale_v > 0.0 && s.full_scale_v <= 1e4) {
        p.push(
            format!("{k}.full_scale_v"),
            s.full_scale_v,
            "must be finite and 0 < full scale <= 1e4 V",
        );
    }
    SensorSpec {
        sensitivity_v_per_g: sens,
        ac_corner_hz: s.ac_corner_hz,
        noise_g_rms: s.noise_g_rms,
        adc_bits: s.adc_bits,
        full_scale_v: s.full_scale_v,
    }
}

impl Rates {
    /// The rule a record or flight length of `seconds` breaks, if any: finite,
    /// 0 < length <= 1e6 s and a whole number of output intervals. The one place of the
    /// rule, shared by the files and `vibrocomp sim --duration-s`.
    pub fn length_problem(&self, seconds: f64) -> Option<String> {
        if !(seconds.is_finite() && seconds > 0.0 && seconds <= 1e6) {
            return Some("must be finite and 0 < length <= 1e6 s".to_string());
        }
        if whole(seconds * self.output_hz).is_none() {
            return Some(format!(
                "must be a whole number of output intervals (1/output_hz = {} s)",
                1.0 / self.output_hz
            ));
        }
        None
    }
}

/// A record or flight length that must hold a whole number of output intervals.
fn check_length(key: &str, seconds: f64, rates: &Rates, p: &mut Problems) -> bool {
    match rates.length_problem(seconds) {
        Some(rule) => {
            p.push(key, seconds, rule);
            false
        }
        None => true,
    }
}

fn validate_flight(
    f: &FlightRaw,
    rates: &Rates,
    refs: &Refs<'_>,
    p: &mut Problems,
) -> Option<Flight> {
    check_length("flight.duration_s", f.duration_s, rates, p);
    let mut triad = match refs.triad(&f.triad) {
        Ok(t) => Some(t),
        Err(e) => {
            p.push("flight.triad", format!("{:?}", f.triad), e);
            None
        }
    };
    if let Some(list) = &f.passports {
        if list.len() != 3 {
            p.push(
                "flight.passports",
                format!("{list:?}"),
                "must list exactly 3 passports, one per unit",
            );
        }
        for (i, arg) in list.iter().enumerate().take(3) {
            match refs.passport(arg) {
                Ok(pp) => {
                    if let Some(t) = triad.as_mut() {
                        t.passports[i] = pp;
                    }
                }
                Err(e) => p.push(format!("flight.passports[{i}]"), format!("{arg:?}"), e),
            }
        }
    }
    if f.profile.is_empty() {
        p.note("flight.profile: no points: at least one [[flight.profile]] is required".into());
    }
    let mut previous_t = f64::NEG_INFINITY;
    for (i, pt) in f.profile.iter().enumerate() {
        let key = format!("flight.profile[{i}]");
        if i == 0 && pt.t_s != 0.0 {
            p.push(
                format!("{key}.t_s"),
                pt.t_s,
                "the first point must be at 0 s",
            );
        } else if !(pt.t_s.is_finite() && pt.t_s > previous_t) {
            p.push(
                format!("{key}.t_s"),
                pt.t_s,
                format!("must be finite and greater than the previous t_s = {previous_t}"),
            );
        }
        if pt.t_s.is_finite() {
            previous_t = pt.t_s;
        }
        for (a, v) in pt.accel_body_g.iter().enumerate() {
            if let Some(rule) = vibro_physics::vibration::rules::flight_accel_g(*v) {
                p.push(format!("{key}.accel_body_g[{a}]"), v, rule);
            }
        }
    }
    if f.tone.len() > MAX_TONES {
        p.push(
            "flight.tone",
            format!("{} tones", f.tone.len()),
            format!("at most {MAX_TONES} tones are supported"),
        );
    }
    let mut tones = Vec::new();
    for (k, t) in f.tone.iter().enumerate() {
        let key = format!("flight.tone[{k}]");
        check_tone_freq(&format!("{key}.freq_hz"), t.freq_hz, rates, p);
        if let Some(to) = t.sweep_to_hz {
            check_tone_freq(&format!("{key}.sweep_to_hz"), to, rates, p);
        }
        for (i, a) in t.amplitude_g.iter().enumerate() {
            if !(a.is_finite() && (0.0..=1e3).contains(a)) {
                p.push(
                    format!("{key}.amplitude_g[{i}]"),
                    a,
                    "must be finite and 0 <= amplitude <= 1000 g",
                );
            }
        }
        let phase_deg = t.phase_deg.unwrap_or([0.0; 3]);
        for (i, ph) in phase_deg.iter().enumerate() {
            if !ph.is_finite() {
                p.push(format!("{key}.phase_deg[{i}]"), ph, "must be finite");
            }
        }
        tones.push(FlightTone {
            tone: Tone {
                freq_hz: t.freq_hz,
                amplitude_g: t.amplitude_g,
                phase_rad: phase_deg.map(f64::to_radians),
            },
            sweep_to_hz: t.sweep_to_hz,
        });
    }
    let random = f
        .random
        .as_ref()
        .and_then(|r| validate_random(r, rates, refs, p));
    Some(Flight {
        duration_s: f.duration_s,
        triad: triad?,
        profile: Profile::from_points(
            f.profile
                .iter()
                .map(|pt| (pt.t_s, pt.accel_body_g))
                .collect(),
        ),
        tones,
        random,
    })
}

fn check_coherence(key: &str, c: &[[f64; 3]; 3], p: &mut Problems) {
    let mut ok = true;
    for i in 0..3 {
        for j in 0..3 {
            let v = c[i][j];
            if i == j && v != 1.0 {
                p.push(format!("{key}[{i}][{j}]"), v, "the diagonal must be 1");
                ok = false;
            } else if !(v.is_finite() && v.abs() <= 1.0) {
                p.push(
                    format!("{key}[{i}][{j}]"),
                    v,
                    "must be finite and within -1..=1",
                );
                ok = false;
            } else if (v - c[j][i]).abs() > 1e-12 {
                p.push(
                    format!("{key}[{i}][{j}]"),
                    v,
                    format!("must equal {key}[{j}][{i}] = {} (symmetric)", c[j][i]),
                );
                ok = false;
            }
        }
    }
    if ok {
        let r = cholesky_residual(c);
        if r > 1e-9 {
            p.push(
                key,
                format!("{c:?}"),
                format!("must be positive semi-definite (a correlation matrix); its Cholesky factor misses it by {r:.3e}"),
            );
        }
    }
}

fn validate_random(
    r: &RandomRaw,
    rates: &Rates,
    refs: &Refs<'_>,
    p: &mut Problems,
) -> Option<RandomSpec> {
    let key = "flight.random";
    let given = [
        r.psd_table.is_some(),
        r.psd_tables.is_some(),
        r.band.is_some(),
    ];
    if given.iter().filter(|g| **g).count() != 1 {
        p.note(format!(
            "{key}: give exactly one of psd_table, psd_tables and [[{key}.band]]"
        ));
        return None;
    }
    let mut source;
    let mut shapes: [Vec<(f64, f64, f64)>; 3] = Default::default();
    if let Some(arg) = &r.psd_table {
        match refs.psd(arg) {
            Ok((bands, name)) => {
                let s = psd3_shape(&format!("{key}.psd_table"), arg, &bands, p);
                shapes = [s.clone(), s.clone(), s];
                source = name;
            }
            Err(e) => {
                p.push(format!("{key}.psd_table"), format!("{arg:?}"), e);
                return None;
            }
        }
    } else if let Some(args) = &r.psd_tables {
        let mut names = Vec::new();
        for (i, arg) in args.iter().enumerate() {
            match refs.psd(arg) {
                Ok((bands, name)) => {
                    shapes[i] = psd3_shape(&format!("{key}.psd_tables[{i}]"), arg, &bands, p);
                    names.push(name);
                }
                Err(e) => p.push(format!("{key}.psd_tables[{i}]"), format!("{arg:?}"), e),
            }
        }
        source = names.join("/");
    } else {
        let bands = r.band.as_deref().unwrap_or_default();
        if bands.is_empty() {
            p.note(format!("{key}.band: no bands: at least one is required"));
        }
        let mut s = Vec::new();
        for (i, b) in bands.iter().enumerate() {
            let k = format!("{key}.band[{i}]");
            if !(b.f_lo_hz.is_finite() && b.f_lo_hz >= 0.0) {
                p.push(
                    format!("{k}.f_lo_hz"),
                    b.f_lo_hz,
                    "must be finite and >= 0 Hz",
                );
            }
            if !(b.f_hi_hz.is_finite() && b.f_hi_hz > b.f_lo_hz) {
                p.push(
                    format!("{k}.f_hi_hz"),
                    b.f_hi_hz,
                    format!("must be finite and exceed f_lo_hz = {}", b.f_lo_hz),
                );
            }
            if !(b.psd_g2_per_hz.is_finite() && (0.0..=1e4).contains(&b.psd_g2_per_hz)) {
                p.push(
                    format!("{k}.psd_g2_per_hz"),
                    b.psd_g2_per_hz,
                    "must be finite within 0..=1e4 g^2/Hz",
                );
            }
            s.push((b.f_lo_hz, b.f_hi_hz, b.psd_g2_per_hz));
        }
        shapes = [s.clone(), s.clone(), s];
        source = "inline bands".into();
    }
    if let Some(gains) = &r.band_gain {
        if r.psd_tables.is_some() {
            p.push(
                format!("{key}.band_gain"),
                format!("{gains:?}"),
                "only with a single psd_table or inline bands",
            );
        } else if gains.len() != shapes[0].len() {
            p.push(
                format!("{key}.band_gain"),
                format!("{gains:?}"),
                format!("must give one gain per band ({} bands)", shapes[0].len()),
            );
        } else {
            for (i, g) in gains.iter().enumerate() {
                if !(g.is_finite() && (0.0..=1e3).contains(g)) {
                    p.push(
                        format!("{key}.band_gain[{i}]"),
                        g,
                        "must be finite within 0..=1000",
                    );
                }
            }
            for shape in shapes.iter_mut() {
                for (b, g) in shape.iter_mut().zip(gains) {
                    b.2 *= g * g;
                }
            }
            source += " x band gains";
        }
    }
    let variance: Vec<f64> = shapes
        .iter()
        .map(|s| s.iter().map(|b| b.2 * (b.1 - b.0)).sum())
        .collect();
    let scale = match (r.scale, r.rms_g) {
        (Some(_), Some(_)) => {
            p.note(format!("{key}: give scale or rms_g, not both"));
            [1.0; 3]
        }
        (Some(s), None) => {
            for (i, v) in s.iter().enumerate() {
                if !(v.is_finite() && (0.0..=1e3).contains(v)) {
                    p.push(
                        format!("{key}.scale[{i}]"),
                        v,
                        "must be finite within 0..=1000",
                    );
                }
            }
            source += &format!(" x scale {s:?}");
            s
        }
        (None, Some(rms)) => {
            let mut s = [1.0; 3];
            for i in 0..3 {
                if !(rms[i].is_finite() && (0.0..=1e3).contains(&rms[i])) {
                    p.push(
                        format!("{key}.rms_g[{i}]"),
                        rms[i],
                        "must be finite within 0..=1000 g",
                    );
                } else if rms[i] > 0.0 && variance[i] <= 0.0 {
                    p.push(
                        format!("{key}.rms_g[{i}]"),
                        rms[i],
                        "the PSD of this axis is zero: nothing to scale",
                    );
                } else if rms[i] > 0.0 {
                    s[i] = rms[i] / variance[i].sqrt();
                } else {
                    s[i] = 0.0;
                }
            }
            source += &format!(" at rms {rms:?} g");
            s
        }
        (None, None) => [1.0; 3],
    };
    for (shape, s) in shapes.iter_mut().zip(scale) {
        for b in shape.iter_mut() {
            b.2 *= s * s;
        }
    }
    let bands = merge_axes(&shapes);
    let coherence = r
        .coherence
        .unwrap_or([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
    check_coherence(&format!("{key}.coherence"), &coherence, p);
    let kurtosis = r.kurtosis.unwrap_or([3.0; 3]);
    for (i, k) in kurtosis.iter().enumerate() {
        check_kurtosis(&format!("{key}.kurtosis[{i}]"), *k, p);
    }
    let (segment_s, filter_resolution_hz) = random_numerics(
        key,
        r.kurtosis_segment_s,
        r.filter_resolution_hz,
        &bands,
        rates,
        p,
    );
    Some(RandomSpec {
        source,
        setup: RandomSetup {
            bands,
            coherence,
            kurtosis,
            segment_s,
            filter_resolution_hz,
        },
    })
}

fn validate_campaign(
    c: &CampaignRaw,
    rates: &Rates,
    refs: &Refs<'_>,
    p: &mut Problems,
) -> Option<Campaign> {
    let passport = match refs.passport(&c.passport) {
        Ok(pp) => Some(pp),
        Err(e) => {
            p.push("campaign.passport", format!("{:?}", c.passport), e);
            None
        }
    };
    let batches = c.batches.unwrap_or(DEFAULT_BATCHES);
    if !(2..=10_000).contains(&batches) {
        p.push("campaign.batches", batches, "must be 2..=10000");
    }
    for (key, len) in [
        ("campaign.still_s", c.still_s),
        ("campaign.vibrating_s", c.vibrating_s),
    ] {
        if check_length(key, len, rates, p) && (len * rates.output_hz).round() < batches as f64 {
            p.push(
                key,
                len,
                format!("must hold at least {batches} output samples, one per batch"),
            );
        }
    }
    let settle_s = c.settle_s.unwrap_or(0.0);
    let settle_out = settle_s * rates.output_hz;
    if !(settle_s.is_finite() && settle_s >= 0.0 && (settle_out - settle_out.round()).abs() < 1e-6)
    {
        p.push(
            "campaign.settle_s",
            settle_s,
            "must be finite, >= 0 and a whole number of output intervals",
        );
    } else {
        for (key, len) in [
            ("campaign.still_s", c.still_s),
            ("campaign.vibrating_s", c.vibrating_s),
        ] {
            if ((len - settle_s) * rates.output_hz).round() < batches as f64 {
                p.push(
                    key,
                    len,
                    format!(
                        "must hold at least {batches} output samples after settle_s = {settle_s}"
                    ),
                );
            }
        }
    }
    let tilt_limit_rad = c.tilt_limit_rad.unwrap_or(DEFAULT_TILT_LIMIT_RAD);
    if !(tilt_limit_rad.is_finite() && tilt_limit_rad > 0.0) {
        p.push(
            "campaign.tilt_limit_rad",
            tilt_limit_rad,
            "must be finite and > 0 rad",
        );
    }
    if c.grid.is_empty() {
        p.note("campaign.grid: no grids: at least one [[campaign.grid]] is required".into());
    }
    let mut conditions = Vec::new();
    for (g, grid) in c.grid.iter().enumerate() {
        expand_grid(g, grid, rates, refs, p, &mut conditions);
    }
    Some(Campaign {
        passport: passport?,
        passport_source: c.passport.clone(),
        still_s: c.still_s,
        vibrating_s: c.vibrating_s,
        batches,
        tilt_limit_rad,
        settle_s,
        conditions,
    })
}
