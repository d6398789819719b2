//! The grid expansion of a campaign: each `[[campaign.grid]]` table (lists of
//! angles, directions, tones and random levels) into its conditions, the product of
//! its lists in file order.

use super::checks::{
    check_kurtosis, check_tone_freq, merge_axes, psd3_shape, random_numerics, Problems,
};
use super::raw::GridRaw;
use super::types::{Condition, Direction, RandomSpec, Rates, TiltAxis};
use super::{Refs, DEFAULT_FILTER_RESOLUTION_HZ, DEFAULT_KURTOSIS_SEGMENT_S};
use crate::random::RandomSetup;
use vibro_physics::vibration::Tone;

/// A random level of a grid: an amplitude scale of the table or an RMS, along the
/// direction.
#[derive(Debug, Clone, Copy)]
enum Level {
    Scale(f64),
    Rms(f64),
}

/// One random level of a grid: table name, its psd3 shape, level and kurtosis.
type GridRandom = (String, Vec<(f64, f64, f64)>, Level, f64);

pub(super) fn expand_grid(
    g: usize,
    grid: &GridRaw,
    rates: &Rates,
    refs: &Refs<'_>,
    p: &mut Problems,
    out: &mut Vec<Condition>,
) {
    let key = format!("campaign.grid[{g}]");
    let nonempty = |name: &str, n: usize, p: &mut Problems| {
        if n == 0 {
            p.note(format!("{key}.{name}: empty list: give at least one value"));
        }
    };
    nonempty("angle_deg", grid.angle_deg.len(), p);
    for (i, a) in grid.angle_deg.iter().enumerate() {
        if !a.is_finite() {
            p.push(format!("{key}.angle_deg[{i}]"), a, "must be finite");
        }
    }
    let tilt = match grid.tilt_toward.trim().to_ascii_lowercase().as_str() {
        "oa" => TiltAxis::Oa,
        "pa" => TiltAxis::Pa,
        _ => {
            p.push(
                format!("{key}.tilt_toward"),
                format!("{:?}", grid.tilt_toward),
                "must be \"oa\" or \"pa\" (the axis that takes the rest of gravity)",
            );
            TiltAxis::Oa
        }
    };
    nonempty("direction", grid.direction.len(), p);
    let mut directions = Vec::new();
    for (i, d) in grid.direction.iter().enumerate() {
        match Direction::parse(d) {
            Some(d) => directions.push(d),
            None => p.push(
                format!("{key}.direction[{i}]"),
                format!("{d:?}"),
                "must be \"ia\", \"ia-oa-45\" or \"ia-pa-45\"",
            ),
        }
    }
    let sqrt2 = grid.scale_45_by_sqrt2.unwrap_or(false);
    // Tones: amplitude x frequency, or none.
    let tones: Vec<Option<(f64, f64)>> = match (&grid.tone_amplitude_g, &grid.tone_freq_hz) {
        (Some(amps), Some(freqs)) => {
            nonempty("tone_amplitude_g", amps.len(), p);
            nonempty("tone_freq_hz", freqs.len(), p);
            for (i, a) in amps.iter().enumerate() {
                if !(a.is_finite() && *a > 0.0 && *a <= 500.0) {
                    p.push(
                        format!("{key}.tone_amplitude_g[{i}]"),
                        a,
                        "must be finite and 0 < amplitude <= 500 g",
                    );
                }
            }
            for (i, f) in freqs.iter().enumerate() {
                check_tone_freq(&format!("{key}.tone_freq_hz[{i}]"), *f, rates, p);
            }
            amps.iter()
                .flat_map(|a| freqs.iter().map(move |f| Some((*a, *f))))
                .collect()
        }
        (None, None) => vec![None],
        _ => {
            p.note(format!(
                "{key}: tone_amplitude_g and tone_freq_hz go together: give both or neither"
            ));
            vec![None]
        }
    };
    // Random: table x level x kurtosis, or none.
    let mut randoms: Vec<Option<GridRandom>> = vec![None];
    let mut numerics = (DEFAULT_KURTOSIS_SEGMENT_S, DEFAULT_FILTER_RESOLUTION_HZ);
    if let Some(tables) = &grid.psd_table {
        nonempty("psd_table", tables.len(), p);
        let levels: Vec<Level> = match (&grid.random_scale, &grid.random_rms_g) {
            (Some(_), Some(_)) => {
                p.note(format!(
                    "{key}: give random_scale or random_rms_g, not both"
                ));
                vec![]
            }
            (Some(s), None) => {
                nonempty("random_scale", s.len(), p);
                for (i, v) in s.iter().enumerate() {
                    if !(v.is_finite() && *v > 0.0 && *v <= 1e3) {
                        p.push(
                            format!("{key}.random_scale[{i}]"),
                            v,
                            "must be finite within 0 < scale <= 1000",
                        );
                    }
                }
                s.iter().map(|v| Level::Scale(*v)).collect()
            }
            (None, Some(r)) => {
                nonempty("random_rms_g", r.len(), p);
                for (i, v) in r.iter().enumerate() {
                    if !(v.is_finite() && *v > 0.0 && *v <= 1e3) {
                        p.push(
                            format!("{key}.random_rms_g[{i}]"),
                            v,
                            "must be finite within 0 < rms <= 1000 g",
                        );
                    }
                }
                r.iter().map(|v| Level::Rms(*v)).collect()
            }
            (None, None) => vec![Level::Scale(1.0)],
        };
        let kurtoses = grid.kurtosis.clone().unwrap_or_else(|| vec![3.0]);
        nonempty("kurtosis", kurtoses.len(), p);
        for (i, k) in kurtoses.iter().enumerate() {
            check_kurtosis(&format!("{key}.kurtosis[{i}]"), *k, p);
        }
        randoms.clear();
        let mut all_bands = Vec::new();
        for (i, arg) in tables.iter().enumerate() {
            match refs.psd(arg) {
                Ok((bands, name)) => {
                    let shape = psd3_shape(&format!("{key}.psd_table[{i}]"), arg, &bands, p);
                    let variance: f64 = shape.iter().map(|b| b.2 * (b.1 - b.0)).sum();
                    if variance <= 0.0 {
                        p.push(
                            format!("{key}.psd_table[{i}]"),
                            format!("{arg:?}"),
                            "has no power along the direction (psd3 column all zero)",
                        );
                    }
                    all_bands.extend(bands);
                    for level in &levels {
                        for k in &kurtoses {
                            randoms.push(Some((name.clone(), shape.clone(), *level, *k)));
                        }
                    }
                }
                Err(e) => p.push(format!("{key}.psd_table[{i}]"), format!("{arg:?}"), e),
            }
        }
        numerics = random_numerics(
            &key,
            grid.kurtosis_segment_s,
            grid.filter_resolution_hz,
            &all_bands,
            rates,
            p,
        );
    } else if grid.random_scale.is_some() || grid.random_rms_g.is_some() || grid.kurtosis.is_some()
    {
        p.note(format!(
            "{key}: random_scale, random_rms_g and kurtosis need psd_table"
        ));
    }
    if tones == [None] && randoms.iter().all(Option::is_none) {
        p.note(format!(
            "{key}: no vibration: give tone_amplitude_g/tone_freq_hz, psd_table, or both"
        ));
    }
    for &angle_deg in &grid.angle_deg {
        let g3 = vibro_ident::cos_deg(angle_deg);
        let g_tilt = vibro_ident::cos_deg(angle_deg - 90.0);
        let a_l_unit_g = match tilt {
            TiltAxis::Oa => [g_tilt, 0.0, g3],
            TiltAxis::Pa => [0.0, g_tilt, g3],
        };
        for &direction in &directions {
            let factors = direction.axis_factors(sqrt2);
            for tone in &tones {
                for random in &randoms {
                    let index = out.len();
                    let tone_spec = tone.map(|(a, f)| Tone {
                        freq_hz: f,
                        amplitude_g: factors.map(|k| k * a),
                        phase_rad: [0.0; 3],
                    });
                    let random_spec = random.as_ref().map(|(name, shape, level, k)| {
                        let variance: f64 = shape.iter().map(|b| b.2 * (b.1 - b.0)).sum();
                        let (along, label) = match *level {
                            Level::Scale(s) => (s, format!("{name} x{s}")),
                            Level::Rms(r) => (
                                if variance > 0.0 {
                                    r / variance.sqrt()
                                } else {
                                    0.0
                                },
                                format!("{name} at {r} g rms"),
                            ),
                        };
                        let per_axis: [Vec<(f64, f64, f64)>; 3] = std::array::from_fn(|i| {
                            let s = along * factors[i];
                            shape.iter().map(|b| (b.0, b.1, b.2 * s * s)).collect()
                        });
                        let bands = merge_axes(&per_axis);
                        // Axes moved by the shaker are fully coherent (one drive signal).
                        let mut coherence = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
                        for i in 0..3 {
                            for j in 0..3 {
                                if i != j && factors[i] != 0.0 && factors[j] != 0.0 {
                                    coherence[i][j] = 1.0;
                                }
                            }
                        }
                        let (segment_s, filter_resolution_hz) = numerics;
                        RandomSpec {
                            source: label,
                            setup: RandomSetup {
                                bands,
                                coherence,
                                kurtosis: [*k; 3],
                                segment_s,
                                filter_resolution_hz,
                            },
                        }
                    });
                    out.push(Condition {
                        index,
                        id: format!("C{:03}", index + 1),
                        tp: u32::try_from(index + 1).unwrap_or(u32::MAX),
                        angle_deg,
                        tilt_toward: tilt,
                        a_l_unit_g,
                        direction,
                        scale_45_by_sqrt2: sqrt2,
                        tone: tone_spec,
                        tone_amplitude_g: tone.map(|t| t.0),
                        random: random_spec,
                    });
                }
            }
        }
    }
}
