//! Accelerometer passports: `config/accelerometers/*.toml`.

use crate::{read, ConfigError, Result};
use std::path::Path;
use vibro_physics::passport::{Passport, PassportSpec, MAX_LAMBDA_POINTS};

/// Longest passport id, in bytes: what a [`Passport`] holds (a fixed 32-byte field, so
/// that a passport is cheap to copy into a real-time kernel).
const MAX_ID_BYTES: usize = 32;

/// The passports shipped in `config/accelerometers/`: (id, file name, text).
pub const EMBEDDED_PASSPORTS: [(&str, &str, &str); 3] = [
    (
        "AL-15",
        "config/accelerometers/al-15.toml",
        include_str!("../../../config/accelerometers/al-15.toml"),
    ),
    (
        "AL-1M",
        "config/accelerometers/al-1m.toml",
        include_str!("../../../config/accelerometers/al-1m.toml"),
    ),
    (
        "AKS-05",
        "config/accelerometers/aks-05.toml",
        include_str!("../../../config/accelerometers/aks-05.toml"),
    ),
];

/// Parses and validates a passport from TOML text; `file` names it in errors.
pub fn parse_passport(text: &str, file: &str) -> Result<Passport> {
    let spec: PassportSpec = vibro_toml::from_str(text, file)?;
    // Sizes first (the physics' own rules, without quoting a long id whole or
    // checking a long table point by point).
    let mut problems = Vec::new();
    let id_ok = vibro_toml::bounds::text("id", &spec.id, MAX_ID_BYTES, &mut problems);
    let lambda_ok = vibro_toml::bounds::list(
        "lambda",
        spec.lambda.len(),
        MAX_LAMBDA_POINTS,
        &mut problems,
    );
    if !(id_ok && lambda_ok) {
        return Err(ConfigError::Invalid {
            file: file.to_string(),
            problems,
        });
    }
    Passport::try_from_spec(&spec).map_err(|e| match e {
        vibro_physics::Error::InvalidPassport { problems } => ConfigError::Invalid {
            file: file.to_string(),
            problems,
        },
        other => ConfigError::Invalid {
            file: file.to_string(),
            problems: vec![other.to_string()],
        },
    })
}

/// Loads a passport file.
pub fn load_passport(path: &Path) -> Result<Passport> {
    parse_passport(&read(path)?, &path.display().to_string())
}

/// A passport from a path, or from the id of a shipped passport (case-insensitive).
/// An existing file wins over an id.
pub fn resolve_passport(arg: &str) -> Result<Passport> {
    let path = Path::new(arg);
    if path.is_file() {
        return load_passport(path);
    }
    if let Some((_, file, text)) = EMBEDDED_PASSPORTS
        .iter()
        .find(|(id, _, _)| id.eq_ignore_ascii_case(arg))
    {
        return parse_passport(text, &format!("{file} (embedded)"));
    }
    Err(ConfigError::Unknown {
        arg: arg.to_string(),
        kind: "passport",
        known: EMBEDDED_PASSPORTS
            .iter()
            .map(|(id, _, _)| *id)
            .collect::<Vec<_>>()
            .join(", "),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 46, item 7: the id and the lambda table are bounded, checked first (a long
    /// id was quoted whole, a long table checked point by point).
    #[test]
    fn an_id_or_a_table_over_its_bound_is_refused_first() {
        let (_, _, text) = EMBEDDED_PASSPORTS[0];
        let long = text.replace(
            "id = \"AL-15\"",
            &format!("id = \"{}\"", "i".repeat(100_000)),
        );
        let point = "[[lambda]]\nfreq_hz = -1.0\nlambda = 0.0\n";
        let long = format!("{long}\n{}", point.repeat(10_000));
        let e = parse_passport(&long, "p.toml").unwrap_err();
        let ConfigError::Invalid { problems, .. } = &e else {
            panic!("{e}")
        };
        assert_eq!(problems.len(), 2, "{e}");
        assert!(problems[0].starts_with("id = \"iiii"), "{e}");
        assert!(
            problems[0].ends_with("(100000 bytes): at most 32 bytes"),
            "{e}"
        );
        assert_eq!(problems[1], "lambda: 10000 entries: at most 32");
    }

    #[test]
    fn shipped_passports_load_and_carry_the_papers_values() {
        for (id, file, text) in EMBEDDED_PASSPORTS {
            let p = parse_passport(text, file).unwrap();
            assert_eq!(p.id(), id);
        }
        let al15 = resolve_passport("al-15").unwrap();
        let aks = resolve_passport("AKS-05").unwrap();
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-15 * b.abs();
        for (got, want) in [
            (al15.a0_g, 3.324e-3),
            (al15.k[5], 0.9e-6),
            (al15.m31_per_g, 11.6e-6),
            (aks.a0_g, 0.5e-3),
            (aks.d1a, 15e-6),
            (aks.k[4], 0.02e-6),
        ] {
            assert!(close(got, want), "{got} != {want}");
        }
    }

    #[test]
    fn errors_name_file_key_value_and_rule() {
        let text = EMBEDDED_PASSPORTS[0]
            .2
            .replace("k2_ppm_per_g = 105.0", "k2_ppm_per_g = -1e9");
        let e = parse_passport(&text, "x.toml").unwrap_err().to_string();
        assert_eq!(
            e,
            "x.toml: k2_ppm_per_g = -1000000000: must be finite and |k2| <= 1e4 ppm/g"
        );
        let text = format!("{}\nk6_ppm_per_g5 = 1.0\n", EMBEDDED_PASSPORTS[0].2);
        let e = parse_passport(&text, "y.toml").unwrap_err().to_string();
        assert!(
            e.starts_with("y.toml: ") && e.contains("k6_ppm_per_g5: unknown key"),
            "{e}"
        );
        let e = resolve_passport("AL-99").unwrap_err().to_string();
        assert!(e.contains("AL-15, AL-1M, AKS-05"), "{e}");
    }
}
