//! Changes a command line makes to a scenario before it runs: a seed, a flight's
//! length, effects switched off, on, or retuned (`vibrocomp sim --seed --duration-s
//! --no-effects --effect`), and the labels the effects are reported under.
//!
//! An effect is given as `kind` or `kind:key=value,key=value`, the values in TOML
//! syntax (`units=[0,2]` limits it to those units): the same keys as its `[[effect]]`
//! table in a scenario file (docs/effects.md).

use vibro_effects::{catalogue, EffectSpec};

use crate::{Error, Result, Scenario, ScenarioKind};

/// What to change in a scenario; `None`/empty leaves it as the file says.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Overrides {
    /// Replaces the scenario's seed.
    pub seed: Option<u64>,
    /// Replaces a flight's duration, s (checked by the caller against
    /// `Rates::length_problem`; a campaign refuses it).
    pub duration_s: Option<f64>,
    /// Switches off every effect of the scenario (before [`Overrides::effects`]).
    pub no_effects: bool,
    /// Effects switched on, each `kind` or `kind:key=value,...` ([`parse_effect`]).
    pub effects: Vec<String>,
}

/// Applies `overrides` to `scenario`: the seed, a flight's duration, `no_effects`,
/// then each effect in order. `--effect kind` alone switches the scenario's own
/// table of that kind on; with parameters it replaces that table (or adds one).
///
/// The effects are not built here: `crate::scenario_effects` checks their
/// parameters.
pub fn apply_overrides(scenario: &mut Scenario, overrides: &Overrides) -> Result<()> {
    if let Some(seed) = overrides.seed {
        scenario.seed = seed;
    }
    if let Some(d) = overrides.duration_s {
        let ScenarioKind::Flight(flight) = &mut scenario.kind else {
            return Err(Error::Unsupported {
                what: format!("--duration-s = {d}"),
                reason: format!("applies to flights only; {} is a campaign", scenario.name),
            });
        };
        flight.duration_s = d;
    }
    if overrides.no_effects {
        for e in &mut scenario.effects {
            e.enabled = false;
        }
    }
    for text in &overrides.effects {
        let spec = parse_effect(text)?;
        match scenario.effects.iter_mut().find(|e| e.kind == spec.kind) {
            Some(existing) if spec.params.is_empty() && spec.units.is_none() => {
                existing.enabled = true
            }
            Some(existing) => *existing = spec,
            None => scenario.effects.push(spec),
        }
    }
    Ok(())
}

/// Parses `kind` or `kind:key=value,key=value` (values in TOML syntax, arrays
/// allowed) into an effect table. The kind must be in the catalogue; the
/// parameters are checked when the effect is built.
pub fn parse_effect(text: &str) -> Result<EffectSpec> {
    let (kind, rest) = text.split_once(':').unwrap_or((text, ""));
    let kind = kind.trim();
    if !catalogue().iter().any(|e| e.kind == kind) {
        let known: Vec<&str> = catalogue().iter().map(|e| e.kind).collect();
        return Err(Error::UnknownEffect {
            text: text.to_string(),
            kind: kind.to_string(),
            known: known.join(", "),
        });
    }
    let mut table = toml::Table::new();
    for item in split_params(rest) {
        let Some((key, value)) = item.split_once('=') else {
            return Err(Error::EffectItem {
                text: text.to_string(),
                item: item.to_string(),
            });
        };
        let parsed: toml::Table = toml::from_str(&format!("{} = {}", key.trim(), value.trim()))
            .map_err(|source| Error::EffectValue {
                text: text.to_string(),
                item: item.to_string(),
                source: Box::new(source),
            })?;
        table.extend(parsed);
    }
    let mut spec_table = toml::Table::new();
    spec_table.insert("kind".into(), toml::Value::String(kind.to_string()));
    spec_table.extend(table);
    spec_table.try_into().map_err(|source| Error::EffectSpec {
        text: text.to_string(),
        source: Box::new(source),
    })
}

/// Splits `a=1,b=[1,2],c=3` on the commas outside brackets, dropping empty items.
pub fn split_params(text: &str) -> Vec<&str> {
    let (mut out, mut depth, mut start) = (Vec::new(), 0i32, 0);
    for (i, c) in text.char_indices() {
        match c {
            '[' => depth += 1,
            ']' => depth -= 1,
            ',' if depth == 0 => {
                out.push(&text[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    out.push(&text[start..]);
    out.into_iter()
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .collect()
}

/// Each enabled effect as reports and logs name it: `kind`, or
/// `kind(key=value, ...)` with its parameters.
pub fn effect_labels(scenario: &Scenario) -> Vec<String> {
    scenario
        .effects
        .iter()
        .filter(|e| e.enabled)
        .map(|e| {
            if e.params.is_empty() {
                e.kind.clone()
            } else {
                let params: Vec<String> =
                    e.params.iter().map(|(k, v)| format!("{k}={v}")).collect();
                format!("{}({})", e.kind, params.join(", "))
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn params_split_on_commas_outside_brackets() {
        assert_eq!(
            split_params(" a=1, b=[1,2] ,,c=3 "),
            vec!["a=1", "b=[1,2]", "c=3"]
        );
        assert!(split_params("").is_empty());
    }

    #[test]
    fn an_effect_parses_with_toml_values() {
        let kind = catalogue()[0].kind;
        let spec = parse_effect(&format!("{kind}:units=[0,2]")).unwrap();
        assert_eq!(spec.kind, kind);
        assert_eq!(spec.units, Some(vec![0, 2]));
        assert!(spec.enabled);
        assert!(spec.params.is_empty());
    }

    #[test]
    fn bad_effects_are_named() {
        let e = parse_effect("no-such-effect").unwrap_err().to_string();
        assert!(
            e.starts_with("--effect \"no-such-effect\": unknown kind \"no-such-effect\"; known: "),
            "{e}"
        );
        let kind = catalogue()[0].kind;
        let e = parse_effect(&format!("{kind}:q")).unwrap_err().to_string();
        assert_eq!(e, format!("--effect \"{kind}:q\": \"q\" is not key=value"));
        let e = parse_effect(&format!("{kind}:q=abc")).unwrap_err();
        assert!(matches!(e, Error::EffectValue { .. }), "{e}");
    }

    #[test]
    fn labels_list_enabled_effects_with_their_parameters() {
        let mut scenario = crate::resolve_scenario("cyclone-4-short").unwrap();
        scenario.effects.clear();
        let kinds: Vec<&str> = catalogue().iter().map(|e| e.kind).take(2).collect();
        let overrides = Overrides {
            effects: vec![kinds[0].to_string(), format!("{}:x_hz=2.5", kinds[1])],
            ..Overrides::default()
        };
        apply_overrides(&mut scenario, &overrides).unwrap();
        assert_eq!(
            effect_labels(&scenario),
            vec![kinds[0].to_string(), format!("{}(x_hz=2.5)", kinds[1])]
        );
        scenario.effects[0].enabled = false;
        assert_eq!(effect_labels(&scenario).len(), 1);
    }

    #[test]
    fn overrides_set_seed_and_length_and_refuse_a_campaign_length() {
        let mut flight = crate::resolve_scenario("cyclone-4-short").unwrap();
        let overrides = Overrides {
            seed: Some(7),
            duration_s: Some(0.25),
            ..Overrides::default()
        };
        apply_overrides(&mut flight, &overrides).unwrap();
        assert_eq!(flight.seed, 7);
        assert_eq!(flight.flight().unwrap().duration_s, 0.25);
        let mut campaign = crate::resolve_scenario("ten-positions").unwrap();
        let e = apply_overrides(&mut campaign, &overrides).unwrap_err();
        assert!(e.to_string().contains("applies to flights only"), "{e}");
    }
}
