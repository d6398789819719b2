//! The bounds on a scenario's strings and lists (issue 46, item 7), checked before any
//! rule of their meaning: a value over its bound is reported with its key, an excerpt
//! and the bound, and the file is looked at no further (a list of a hundred thousand
//! entries is not checked entry by entry, nor a grid of a million conditions
//! expanded).

use super::raw::{GridRaw, RandomRaw, ScenarioRaw};
use vibro_physics::vibration::MAX_TONES;
use vibro_toml::bounds::{list, text, texts, MAX_NAME_BYTES, MAX_PATH_BYTES, MAX_TEXT_BYTES};

/// Most breakpoints of a flight's profile: the shipped flights have 6 to 10; 10 000
/// hold a 1000 s flight at 10 Hz.
pub const MAX_PROFILE_POINTS: usize = 10_000;
/// Most inline PSD bands (`[[flight.random.band]]`) and band gains: RIG.md's table has
/// 5; 1024 hold a measured PSD in 2 Hz bands across the 2 kHz band of interest.
pub const MAX_INLINE_BANDS: usize = 1024;
/// Most `[[campaign.grid]]` tables.
pub const MAX_GRIDS: usize = 64;
/// Most values of one of a grid's lists (angles, amplitudes, frequencies, levels,
/// kurtoses): one per degree of a full turn.
pub const MAX_GRID_VALUES: usize = 360;
/// Most PSD tables one grid names.
pub const MAX_GRID_TABLES: usize = 64;
/// Most conditions a campaign expands to, over all its grids (each a run of two still
/// records and a vibrating one, minutes of rig time each): section 8's grid has 57.
pub const MAX_CONDITIONS: usize = 10_000;
/// Most `[[effect]]` tables: the catalogue has eleven kinds, each may be given per
/// unit.
pub const MAX_EFFECTS: usize = 64;
/// Longest word: a kind, a direction, an axis (`ia-oa-45`).
const MAX_WORD_BYTES: usize = 64;

/// Whether every string and list of `raw` is within its bound; each one over added
/// to `p`.
pub(super) fn check_sizes(raw: &ScenarioRaw, p: &mut Vec<String>) -> bool {
    let mut ok = text("name", &raw.name, MAX_NAME_BYTES, p);
    if let Some(d) = &raw.description {
        ok &= text("description", d, MAX_TEXT_BYTES, p);
    }
    if let Some(f) = &raw.flight {
        ok &= text("flight.triad", &f.triad, MAX_PATH_BYTES, p);
        if let Some(passports) = &f.passports {
            ok &= passport_list("flight.passports", passports, p);
        }
        ok &= list("flight.profile", f.profile.len(), MAX_PROFILE_POINTS, p);
        ok &= list("flight.tone", f.tone.len(), MAX_TONES, p);
        if let Some(r) = &f.random {
            ok &= random(r, p);
        }
    }
    if let Some(c) = &raw.campaign {
        ok &= text("campaign.passport", &c.passport, MAX_PATH_BYTES, p);
        if list("campaign.grid", c.grid.len(), MAX_GRIDS, p) {
            let mut conditions: usize = 0;
            let mut all_within = true;
            for (g, grid) in c.grid.iter().enumerate() {
                all_within &= grid_lists(&format!("campaign.grid[{g}]"), grid, p);
                conditions = conditions.saturating_add(grid_conditions(grid));
            }
            ok &= all_within;
            if all_within && conditions > MAX_CONDITIONS {
                p.push(format!(
                    "campaign.grid: {conditions} conditions (the product of each grid's lists): at most {MAX_CONDITIONS}"
                ));
                ok = false;
            }
        } else {
            ok = false;
        }
    }
    if list("effect", raw.effect.len(), MAX_EFFECTS, p) {
        for (i, e) in raw.effect.iter().enumerate() {
            ok &= text(&format!("effect[{i}].kind"), &e.kind, MAX_WORD_BYTES, p);
            if let Some(units) = &e.units {
                ok &= list(&format!("effect[{i}].units"), units.len(), 3, p);
            }
            ok &= list(
                &format!("effect[{i}]"),
                e.params.len(),
                vibro_effects::MAX_EFFECT_PARAMS,
                p,
            );
        }
    } else {
        ok = false;
    }
    ok
}

/// A list of one passport per unit: exactly 3, each a file or a shipped id.
fn passport_list(key: &str, passports: &[String], p: &mut Vec<String>) -> bool {
    if passports.len() != 3 {
        p.push(format!(
            "{key}: {} entries: must list exactly 3 passports, one per unit",
            passports.len()
        ));
        return false;
    }
    texts(key, passports, 3, MAX_PATH_BYTES, p)
}

fn random(r: &RandomRaw, p: &mut Vec<String>) -> bool {
    let key = "flight.random";
    let mut ok = true;
    if let Some(t) = &r.psd_table {
        ok &= text(&format!("{key}.psd_table"), t, MAX_PATH_BYTES, p);
    }
    if let Some(tables) = &r.psd_tables {
        for (i, t) in tables.iter().enumerate() {
            ok &= text(&format!("{key}.psd_tables[{i}]"), t, MAX_PATH_BYTES, p);
        }
    }
    if let Some(b) = &r.band {
        ok &= list(&format!("{key}.band"), b.len(), MAX_INLINE_BANDS, p);
    }
    if let Some(g) = &r.band_gain {
        ok &= list(&format!("{key}.band_gain"), g.len(), MAX_INLINE_BANDS, p);
    }
    ok
}

fn grid_lists(key: &str, g: &GridRaw, p: &mut Vec<String>) -> bool {
    let values = |name: &str, v: Option<usize>, p: &mut Vec<String>| {
        v.is_none_or(|n| list(&format!("{key}.{name}"), n, MAX_GRID_VALUES, p))
    };
    let mut ok = values("angle_deg", Some(g.angle_deg.len()), p);
    ok &= text(
        &format!("{key}.tilt_toward"),
        &g.tilt_toward,
        MAX_WORD_BYTES,
        p,
    );
    // Three directions exist; one may be listed twice on purpose (a repeat run).
    ok &= texts(
        &format!("{key}.direction"),
        &g.direction,
        MAX_GRID_VALUES,
        MAX_WORD_BYTES,
        p,
    );
    ok &= values(
        "tone_amplitude_g",
        g.tone_amplitude_g.as_ref().map(Vec::len),
        p,
    );
    ok &= values("tone_freq_hz", g.tone_freq_hz.as_ref().map(Vec::len), p);
    if let Some(t) = &g.psd_table {
        ok &= texts(
            &format!("{key}.psd_table"),
            t,
            MAX_GRID_TABLES,
            MAX_PATH_BYTES,
            p,
        );
    }
    ok &= values("random_scale", g.random_scale.as_ref().map(Vec::len), p);
    ok &= values("random_rms_g", g.random_rms_g.as_ref().map(Vec::len), p);
    ok &= values("kurtosis", g.kurtosis.as_ref().map(Vec::len), p);
    ok
}

/// How many conditions `g` expands to (`grid.rs`): angles x directions x tones
/// (amplitudes x frequencies, or none) x random runs (tables x levels x kurtoses, or
/// none).
fn grid_conditions(g: &GridRaw) -> usize {
    let len = |v: &Option<Vec<f64>>| v.as_ref().map_or(1, Vec::len);
    let tones = match (&g.tone_amplitude_g, &g.tone_freq_hz) {
        (Some(a), Some(f)) => a.len().saturating_mul(f.len()),
        _ => 1,
    };
    let randoms = match &g.psd_table {
        Some(t) => t
            .len()
            .saturating_mul(len(&g.random_scale).max(len(&g.random_rms_g)))
            .saturating_mul(len(&g.kurtosis)),
        None => 1,
    };
    g.angle_deg
        .len()
        .saturating_mul(g.direction.len())
        .saturating_mul(tones)
        .saturating_mul(randoms)
}

#[cfg(test)]
mod tests {
    use super::super::parse_scenario;
    use super::MAX_PROFILE_POINTS;
    use crate::Error;

    fn problems(text: &str) -> Vec<String> {
        match parse_scenario(text, "s.toml", None) {
            Err(Error::Scenario { problems, .. }) => problems,
            other => panic!("{:?}", other.map(|s| s.name)),
        }
    }

    /// Issue 46, item 7: every string and list of a scenario is bounded, checked
    /// first, each one over its bound reported at once.
    #[test]
    fn strings_and_lists_over_their_bounds_are_refused_first() {
        let flight = include_str!("../../../../config/scenarios/cyclone-4-short.toml")
            .replace(
                "name = \"cyclone-4-short\"",
                &format!("name = \"{}\"", "n".repeat(100_000)),
            )
            .replace(
                "triad = \"default\"",
                &format!(
                    "triad = \"default\"\npassports = [{}]",
                    ["\"AL-15\""; 4].join(", ")
                ),
            );
        let profile = "[[flight.profile]]\nt_s = 0.0\naccel_body_g = [1.0, 0.0, 0.0]\n";
        let flight = format!("{flight}\n{}", profile.repeat(MAX_PROFILE_POINTS));
        let p = problems(&flight);
        assert_eq!(p.len(), 3, "{p:?}");
        assert!(p[0].starts_with("name = \"nnnn"), "{p:?}");
        assert!(p[0].ends_with("(100000 bytes): at most 128 bytes"), "{p:?}");
        assert_eq!(
            p[1],
            "flight.passports: 4 entries: must list exactly 3 passports, one per unit"
        );
        assert!(
            p[2].starts_with("flight.profile: 1000") && p[2].ends_with("at most 10000"),
            "{p:?}"
        );

        // A grid whose lists are each within bounds, but whose product is not.
        let grid = include_str!("../../../../config/scenarios/section8-grid.toml").replace(
            "angle_deg = [0.0, 90.0, 180.0]",
            &format!("angle_deg = [{}]", vec!["1.0"; 360].join(", ")),
        );
        let p = problems(&grid.replace(
            "tone_freq_hz = [30.0, 60.0]",
            &format!("tone_freq_hz = [{}]", ["30.0"; 10].join(", ")),
        ));
        assert_eq!(
            p,
            ["campaign.grid: 32403 conditions (the product of each grid's lists): at most 10000"]
        );
        let p = problems(&grid.replace(
            "direction = [\"ia\", \"ia-oa-45\", \"ia-pa-45\"]\nscale_45_by_sqrt2 = true\ntone_amplitude_g = [0.42",
            &format!(
                "direction = [\"{}\"]\nscale_45_by_sqrt2 = true\ntone_amplitude_g = [{}0.42",
                "d".repeat(70),
                "1.0, ".repeat(400)
            ),
        ));
        assert_eq!(p.len(), 2, "{p:?}");
        assert!(
            p[0].starts_with("campaign.grid[0].direction[0] = \"dddd"),
            "{p:?}"
        );
        assert_eq!(
            p[1],
            "campaign.grid[0].tone_amplitude_g: 403 entries: at most 360"
        );
        // The shipped scenarios are all within.
        for (id, file, text) in super::super::EMBEDDED_SCENARIOS {
            parse_scenario(text, file, None).unwrap_or_else(|e| panic!("{id}: {e}"));
        }
    }
}
