//! Triad geometries: `config/triads/*.toml`.

use crate::{read, resolve_passport, ConfigError, Result};
use serde::Deserialize;
use std::path::Path;
use vibro_physics::passport::Passport;
use vibro_physics::triad::{SignedAxis, TriadAxes, UnitAxes};

const EMBEDDED_DEFAULT: (&str, &str) = (
    "config/triads/default.toml",
    include_str!("../../../config/triads/default.toml"),
);

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTriad {
    id: String,
    unit: Vec<RawUnit>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawUnit {
    name: String,
    passport: String,
    ia: String,
    oa: String,
    pa: String,
}

/// A validated triad: geometry, and each unit's name and passport.
#[derive(Debug, Clone)]
pub struct TriadConfig {
    pub id: String,
    pub names: [String; 3],
    pub axes: TriadAxes,
    pub passports: [Passport; 3],
}

/// Parses and validates a triad from TOML text; `file` names it in errors. Passport
/// references are resolved relative to the working directory, or as shipped ids.
pub fn parse_triad(text: &str, file: &str) -> Result<TriadConfig> {
    let raw: RawTriad = vibro_toml::from_str(text, file)?;
    let mut problems = Vec::new();
    if raw.unit.len() != 3 {
        problems.push(format!(
            "unit: {} entries: a triad has exactly 3 units",
            raw.unit.len()
        ));
    }
    let mut units = Vec::new();
    let mut passports = Vec::new();
    for (i, u) in raw.unit.iter().enumerate() {
        let mut axis = |key: &str, text: &str| {
            let a = SignedAxis::parse(text);
            if a.is_none() {
                problems.push(format!(
                    "unit[{i}].{key} = {text:?}: must be a signed body axis such as \"+x\" or \"-z\""
                ));
            }
            a
        };
        let (ia, oa, pa) = (axis("ia", &u.ia), axis("oa", &u.oa), axis("pa", &u.pa));
        if let (Some(ia), Some(oa), Some(pa)) = (ia, oa, pa) {
            match UnitAxes::new(ia, oa, pa) {
                Ok(axes) => units.push(axes),
                Err(e) => problems.push(format!("unit[{i}] ({}): {e}", u.name)),
            }
        }
        match resolve_passport(&u.passport) {
            Ok(p) => passports.push(p),
            Err(e) => problems.push(format!("unit[{i}].passport = {:?}: {e}", u.passport)),
        }
    }
    if problems.is_empty() {
        if let (Ok(units), Ok(passports), Ok(names)) = (
            <[UnitAxes; 3]>::try_from(units),
            <[Passport; 3]>::try_from(passports),
            <[String; 3]>::try_from(raw.unit.iter().map(|u| u.name.clone()).collect::<Vec<_>>()),
        ) {
            match TriadAxes::new(units) {
                Ok(axes) => {
                    return Ok(TriadConfig {
                        id: raw.id,
                        names,
                        axes,
                        passports,
                    })
                }
                Err(e) => problems.push(e.to_string()),
            }
        }
    }
    Err(ConfigError::Invalid {
        file: file.to_string(),
        problems,
    })
}

/// Loads a triad file.
pub fn load_triad(path: &Path) -> Result<TriadConfig> {
    parse_triad(&read(path)?, &path.display().to_string())
}

/// The shipped default triad (RIG.md's accelerometer block).
pub fn default_triad() -> Result<TriadConfig> {
    parse_triad(
        EMBEDDED_DEFAULT.1,
        &format!("{} (embedded)", EMBEDDED_DEFAULT.0),
    )
}

/// A triad from a path, or `default` for the shipped one.
pub fn resolve_triad(arg: &str) -> Result<TriadConfig> {
    let path = Path::new(arg);
    if path.is_file() {
        load_triad(path)
    } else if arg.eq_ignore_ascii_case("default") {
        default_triad()
    } else {
        Err(ConfigError::Unknown {
            arg: arg.to_string(),
            kind: "triad",
            known: "default".into(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_triad_is_the_standard_geometry() {
        let t = default_triad().unwrap();
        assert_eq!(t.axes, TriadAxes::standard());
        assert_eq!(t.names[2], "AK3");
        assert_eq!(t.passports[0].id(), "AL-15");
    }

    #[test]
    fn bad_triad_reports_all_problems() {
        let text = EMBEDDED_DEFAULT
            .1
            .replacen("ia = \"+x\"", "ia = \"+w\"", 1)
            .replacen("passport = \"AL-15\"", "passport = \"nope\"", 1);
        let e = parse_triad(&text, "t.toml").unwrap_err().to_string();
        assert!(
            e.starts_with("t.toml: unit[0].ia = \"+w\": must be a signed body axis"),
            "{e}"
        );
        assert!(e.contains("unit[0].passport = \"nope\""), "{e}");
    }
}
