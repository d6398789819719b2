//! The estimates as `vibrocomp estimate` prints them: one row per window (its span, the
//! broadband RMS and kurtosis per column, the flags, the tones), under a header that
//! says what was read and how.

use crate::Estimate;
use std::fmt::Write as _;

/// What the table's header states.
#[derive(Debug, Clone, Copy)]
pub struct TableHeader<'a> {
    pub file: &'a str,
    pub rows: u64,
    pub rate_hz: f64,
    pub columns: &'a [String; 3],
    /// The samples' unit as written (`g`, `V`).
    pub units: &'a str,
    pub window_s: f64,
    pub overlap: f64,
    /// The broadband RMS's band, Hz.
    pub band_hz: [f64; 2],
}

/// Writes the table of `estimates` under `h`.
pub fn write_table(
    out: &mut impl std::io::Write,
    h: &TableHeader<'_>,
    estimates: &[Estimate],
) -> std::io::Result<()> {
    let [lo, hi] = h.band_hz;
    writeln!(
        out,
        "{}: {} rows at {} Hz, columns {} in {}; window {} s, overlap {}: {} windows",
        h.file,
        h.rows,
        h.rate_hz,
        h.columns.join(", "),
        h.units,
        h.window_s,
        h.overlap,
        estimates.len()
    )?;
    writeln!(
        out,
        "{:>9} {:>9}  {:>27}  {:>20}  {:<12} tones: f Hz [amplitude per column, g]",
        "start_s",
        "end_s",
        format!("rms {lo}..{hi} Hz per column, g"),
        "kurtosis per column",
        "flags"
    )?;
    for e in estimates {
        let rms = e.broadband.rms_g.map(fmt_num);
        let kurt = e.broadband.kurtosis.map(|k| fmt_fixed(k, 2));
        let mut tones = String::new();
        for t in e.tones.iter() {
            let a = t.amplitude_g.map(fmt_num);
            let _ = write!(
                tones,
                "{:.3} [{}, {}, {}]  ",
                t.frequency_hz, a[0], a[1], a[2]
            );
        }
        if tones.is_empty() {
            tones.push('-');
        }
        writeln!(
            out,
            "{:>9.3} {:>9.3}  {:>27}  {:>20}  {:<12} {}",
            e.start_ns as f64 * 1e-9,
            e.end_ns as f64 * 1e-9,
            rms.join(", "),
            kurt.join(", "),
            flags_text(e),
            tones.trim_end()
        )?;
    }
    out.flush()
}

/// A value with four significant digits, or `-` when not estimated.
pub fn fmt_num(v: f64) -> String {
    if !v.is_finite() {
        "-".to_string()
    } else if v != 0.0 && (v.abs() < 1e-3 || v.abs() >= 1e4) {
        format!("{v:.3e}")
    } else {
        let digits = (3 - v.abs().log10().floor().max(-3.0) as i32).clamp(0, 6) as usize;
        format!("{v:.digits$}")
    }
}

fn fmt_fixed(v: f64, decimals: usize) -> String {
    if v.is_finite() {
        format!("{v:.decimals$}")
    } else {
        "-".to_string()
    }
}

fn flags_text(e: &Estimate) -> String {
    let labels = e.flags.labels();
    if labels.is_empty() {
        "-".to_string()
    } else {
        labels.join(",")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_keep_four_significant_digits() {
        assert_eq!(fmt_num(1.23456), "1.235");
        assert_eq!(fmt_num(0.0123456), "0.01235");
        assert_eq!(fmt_num(123.456), "123.5");
        assert_eq!(fmt_num(1.5e-5), "1.500e-5");
        assert_eq!(fmt_num(f64::NAN), "-");
        assert_eq!(fmt_fixed(f64::INFINITY, 2), "-");
    }
}
