//! Numbers as the reports print them for people: an acceleration with the engineering
//! prefix that reads best, a ratio. Shared by the renderers here ([`crate::session`])
//! and the commands of `vibrocomp` (re-exported by its `output` module), so that one
//! figure reads the same in every table.

/// An acceleration in g with the prefix that reads best (g from 0.1 g, mg from 0.1 mg,
/// ug from 0.01 ug) and four decimals in it: `11.1409 mg`, `8.7034 ug`; below 1e-8 g
/// in exponent form; 0 as `0 g`.
pub fn fmt_g(value_g: f64) -> String {
    let abs = value_g.abs();
    if abs == 0.0 {
        "0 g".to_string()
    } else if abs >= 0.1 {
        format!("{value_g:.4} g")
    } else if abs >= 1e-4 {
        format!("{:.4} mg", value_g * 1e3)
    } else if abs >= 1e-8 {
        format!("{:.4} ug", value_g * 1e6)
    } else {
        format!("{value_g:.1e} g")
    }
}

/// A ratio such as an error reduction: `34.5x`, or `>1e6x` beyond a million.
pub fn fmt_ratio(ratio: f64) -> String {
    if ratio > 1e6 {
        ">1e6x".to_string()
    } else {
        format!("{ratio:.1}x")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accelerations_take_the_prefix_that_reads_best() {
        assert_eq!(fmt_g(0.0), "0 g");
        assert_eq!(fmt_g(1.25), "1.2500 g");
        assert_eq!(fmt_g(-0.1), "-0.1000 g");
        assert_eq!(fmt_g(11.1409e-3), "11.1409 mg");
        assert_eq!(fmt_g(0.1646e-3), "0.1646 mg");
        assert_eq!(fmt_g(97.5141e-6), "97.5141 ug");
        assert_eq!(fmt_g(2e-9), "2.0e-9 g");
        assert_eq!(fmt_ratio(945.14), "945.1x");
        assert_eq!(fmt_ratio(2e6), ">1e6x");
    }
}
