//! Band PSD tables (`config/vibration/*.csv`): the random-vibration environments of
//! RIG.md as piecewise-constant PSD per axis.
//!
//! Columns (header required, any order): `f_lo_hz, f_hi_hz, psd3_g2_per_hz` and,
//! optionally, `psd1_g2_per_hz, psd2_g2_per_hz` (axes 1 = OA, 2 = PA, 3 = IA of the
//! unit; an absent column or an empty cell means no random vibration on that axis).
//! Lines starting with `#` are comments.

use crate::{read, ConfigError, Result};
use std::path::Path;
use vibro_physics::vibration::PsdBand;

/// Parses a PSD table; `file` names it in errors.
pub fn parse_psd_table(text: &str, file: &str) -> Result<Vec<PsdBand>> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let invalid = |problems: Vec<String>| ConfigError::Invalid {
        file: file.to_string(),
        problems,
    };
    let Some((_, header)) = lines.next() else {
        return Err(invalid(vec![
            "empty table: a header row and at least one band are required".into(),
        ]));
    };
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    let col = |name: &str| names.iter().position(|n| *n == name);
    let known = [
        "f_lo_hz",
        "f_hi_hz",
        "psd1_g2_per_hz",
        "psd2_g2_per_hz",
        "psd3_g2_per_hz",
    ];
    let mut problems: Vec<String> = names
        .iter()
        .filter(|n| !known.contains(n))
        .map(|n| format!("column {n:?}: unknown (known: {})", known.join(", ")))
        .collect();
    for required in ["f_lo_hz", "f_hi_hz", "psd3_g2_per_hz"] {
        if col(required).is_none() {
            problems.push(format!("column {required:?}: missing (required)"));
        }
    }
    if !problems.is_empty() {
        return Err(invalid(problems));
    }
    let (lo, hi) = (col("f_lo_hz"), col("f_hi_hz"));
    let psd_cols = [
        col("psd1_g2_per_hz"),
        col("psd2_g2_per_hz"),
        col("psd3_g2_per_hz"),
    ];
    let mut bands = Vec::new();
    for (line_no, line) in lines {
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        if cells.len() != names.len() {
            problems.push(format!(
                "line {line_no}: {} cells, the header has {}",
                cells.len(),
                names.len()
            ));
            continue;
        }
        let mut number = |c: Option<usize>, rule: fn(f64) -> bool, what: &str| -> f64 {
            let Some(c) = c else { return 0.0 };
            let cell = cells[c];
            if cell.is_empty() && names[c].starts_with("psd") {
                return 0.0;
            }
            match cell.parse::<f64>() {
                Ok(v) if rule(v) => v,
                _ => {
                    problems.push(format!(
                        "line {line_no}, column {}: {cell:?}: {what}",
                        names[c]
                    ));
                    0.0
                }
            }
        };
        let f_lo_hz = number(
            lo,
            |v| v.is_finite() && v >= 0.0,
            "must be a finite frequency >= 0 Hz",
        );
        let f_hi_hz = number(
            hi,
            |v| v.is_finite() && v > 0.0,
            "must be a finite frequency > 0 Hz",
        );
        let mut psd_g2_per_hz = [0.0; 3];
        for (i, c) in psd_cols.iter().enumerate() {
            psd_g2_per_hz[i] = number(
                *c,
                |v| v.is_finite() && (0.0..=1e4).contains(&v),
                "must be a finite PSD in 0..=1e4 g^2/Hz",
            );
        }
        if f_hi_hz <= f_lo_hz {
            problems.push(format!(
                "line {line_no}: f_hi_hz = {f_hi_hz} must exceed f_lo_hz = {f_lo_hz}"
            ));
        }
        bands.push(PsdBand {
            f_lo_hz,
            f_hi_hz,
            psd_g2_per_hz,
        });
    }
    if bands.is_empty() && problems.is_empty() {
        problems.push("no bands: at least one row is required".into());
    }
    if problems.is_empty() {
        Ok(bands)
    } else {
        Err(invalid(problems))
    }
}

/// Loads a PSD table file.
pub fn load_psd_table(path: &Path) -> Result<Vec<PsdBand>> {
    parse_psd_table(&read(path)?, &path.display().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_rig_table_and_rejects_bad_rows() {
        let t =
            parse_psd_table(include_str!("../../../config/vibration/p1-table3.csv"), "t").unwrap();
        assert_eq!(t.len(), 5);
        assert_eq!(
            (t[4].f_lo_hz, t[4].f_hi_hz, t[4].psd_g2_per_hz[2]),
            (320.0, 640.0, 0.12)
        );
        let e = parse_psd_table("f_lo_hz,f_hi_hz,psd3_g2_per_hz\n10,5,x\n", "b.csv").unwrap_err();
        let e = e.to_string();
        assert!(
            e.contains("b.csv: line 2, column psd3_g2_per_hz: \"x\": must be a finite PSD"),
            "{e}"
        );
        assert!(
            e.contains("line 2: f_hi_hz = 5 must exceed f_lo_hz = 10"),
            "{e}"
        );
    }
}
