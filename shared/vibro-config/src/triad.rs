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
    // Sizes first: a value over its bound is not looked at further.
    if !check_sizes(&raw, &mut problems) {
        return Err(ConfigError::Invalid {
            file: file.to_string(),
            problems,
        });
    }
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

/// Every string and list of the file against its bound: whether all are within, each
/// one over added to `p`.
fn check_sizes(raw: &RawTriad, p: &mut Vec<String>) -> bool {
    use vibro_toml::bounds::{text, MAX_NAME_BYTES, MAX_PATH_BYTES};
    // An axis is a sign and a letter (`-z`); a little room for blanks.
    const MAX_AXIS_BYTES: usize = 16;
    let mut ok = text("id", &raw.id, MAX_NAME_BYTES, p);
    if raw.unit.len() > 3 {
        p.push(format!(
            "unit: {} entries: a triad has exactly 3 units",
            raw.unit.len()
        ));
        return false;
    }
    for (i, u) in raw.unit.iter().enumerate() {
        ok &= text(&format!("unit[{i}].name"), &u.name, MAX_NAME_BYTES, p);
        ok &= text(
            &format!("unit[{i}].passport"),
            &u.passport,
            MAX_PATH_BYTES,
            p,
        );
        for (key, axis) in [("ia", &u.ia), ("oa", &u.oa), ("pa", &u.pa)] {
            ok &= text(&format!("unit[{i}].{key}"), axis, MAX_AXIS_BYTES, p);
        }
    }
    ok
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

    /// Issue 46, item 7: every string and list is bounded, checked first.
    #[test]
    fn strings_and_lists_over_their_bounds_are_refused_first() {
        let shipped = EMBEDDED_DEFAULT.1;
        let long_name = shipped.replacen(
            "name = \"AK1\"",
            &format!("name = \"{}\"", "n".repeat(100_000)),
            1,
        );
        assert_ne!(long_name, shipped);
        let e = parse_triad(&long_name, "t.toml").unwrap_err().to_string();
        assert!(e.starts_with("t.toml: unit[0].name = \"nnnn"), "{e}");
        assert!(
            e.ends_with("(100000 bytes): at most 128 bytes") && e.len() < 400,
            "{e}"
        );
        let unit =
            "[[unit]]\nname = \"X\"\npassport = \"AL-15\"\nia = \"+x\"\noa = \"+y\"\npa = \"+z\"\n";
        let many = format!("id = \"m\"\n{}", unit.repeat(10_000));
        let e = parse_triad(&many, "t.toml").unwrap_err().to_string();
        assert_eq!(
            e,
            "t.toml: unit: 10000 entries: a triad has exactly 3 units"
        );
    }

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
