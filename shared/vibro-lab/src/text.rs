//! The lab's results as text, the way `vibrocomp lab` prints them and the report
//! quotes them: a comparison with its largest residuals and its residual by variable,
//! a diagnosis (trends, candidates, the stepwise search, the verdict in words), an
//! empirical correction, a fit's parameters with their uncertainties (profile
//! likelihood where asymmetric) and strong correlations, and what became of a log's
//! windows. Each `write_*` appends lines to a `String`.
//!
//! ```
//! use vibro_lab::text::params_text;
//! use vibro_lab::fit::FittedParam;
//! let p = FittedParam {
//!     effect: "mount_resonance".into(),
//!     name: "freq_hz".into(),
//!     value: 48.0,
//!     sigma: 0.5,
//!     sigma_minus: 0.5,
//!     sigma_plus: 0.5,
//!     three_sigma_minus: 1.5,
//!     three_sigma_plus: 1.5,
//! };
//! assert_eq!(params_text(&[p]), "freq_hz = 4.800000e1 +- 5.00e-1");
//! ```

use crate::diagnose::{Diagnosis, Verdict};
use crate::log_table::LogTableSummary;
use crate::Comparison;
use std::fmt::Write as _;

/// Appends a line to the text.
macro_rules! p {
    ($o:expr) => {{
        let _ = writeln!($o);
    }};
    ($o:expr, $($arg:tt)*) => {{
        let _ = writeln!($o, $($arg)*);
    }};
}

/// One line on what became of a log's windows.
pub fn write_log_summary(o: &mut String, s: &LogTableSummary) {
    p!(
        o,
        "{}: {} conditions from {} of {} estimator windows ({} s, units {}, passports from {}); \
         left out: {} flagged, {} incomplete, {} with aL changing",
        s.log,
        s.conditions,
        s.windows_used,
        s.windows,
        s.estimator_window_s,
        s.units.join(", "),
        s.passports_from,
        s.left_out_flagged,
        s.left_out_incomplete,
        s.left_out_al_span
    );
}

/// One line on a manifest whose estimator bands were clipped to what its reference can
/// see; nothing when none were.
pub fn write_manifest_summary(o: &mut String, s: &crate::inputs::ManifestSummary) {
    let Some(c) = &s.band_clipped else {
        return;
    };
    p!(
        o,
        "{}: the estimator's broadband band {}..{} Hz clipped to {}..{} Hz ({} of the \
         reference's {} Hz) in {} of {} runs; PSD bands cut: {}, left out: {}",
        s.manifest,
        c.broadband_stated_hz[0],
        c.broadband_stated_hz[1],
        c.broadband_used_hz[0],
        c.broadband_used_hz[1],
        crate::campaign::BAND_TOP_FRACTION_OF_RATE,
        c.reference_rate_hz,
        s.runs_band_clipped,
        s.runs,
        c.psd_bands_cut,
        c.psd_bands_left_out
    );
}

fn g(x: f64) -> String {
    format!("{x:>11.3e}")
}

/// `N conditions`, and how many are distinct when some repeat.
fn conditions(s: &crate::diagnose::Summary) -> String {
    if s.distinct_conditions < s.n {
        format!("{} conditions ({} distinct)", s.n, s.distinct_conditions)
    } else {
        format!("{} conditions", s.n)
    }
}

pub fn write_comparison(o: &mut String, c: &Comparison, all: bool) {
    let s = &c.summary;
    let effects = if c.effects.is_empty() {
        "none".to_string()
    } else {
        c.effects.join(", ")
    };
    p!(
        o,
        "{}: {}; model {} mode, effects: {}",
        c.table,
        conditions(s),
        c.mode,
        effects
    );
    p!(
        o,
        "residual RMS {:.3e} g (max {:.3e} g), measured VE RMS {:.3e} g, noise floor {:.3e} g",
        s.rms_residual_g,
        s.max_abs_residual_g,
        s.rms_measured_g,
        s.noise_floor_g
    );
    p!(
        o,
        "chi2 {:.4} for {} dof: {:.4} per dof, p = {:.3e}",
        s.chi2,
        s.dof,
        s.chi2_per_dof,
        s.p_value
    );
    let paths = &c.paths;
    if paths.waveform > 0 {
        p!(
            o,
            "path: waveform for {} conditions (the compensator's waveform stage over the log's \
             samples), statistics for {}",
            paths.waveform,
            paths.statistics
        );
    } else {
        p!(
            o,
            "path: statistics (the model's VE from each condition's stated vibration)"
        );
    }
    let mut rows: Vec<_> = c.rows.iter().collect();
    if !all {
        rows.sort_by(|a, b| b.z.abs().total_cmp(&a.z.abs()));
        rows.truncate(10);
        p!(o, "\nlargest residuals (--all for every condition):");
    } else {
        p!(o);
    }
    p!(
        o,
        "{:<10} {:>5} {:>11} {:>11} {:>11} {:>11} {:>10} {}",
        "run_id",
        "line",
        "measured_g",
        "u_g",
        "predicted_g",
        "residual_g",
        "z",
        "path"
    );
    for r in rows {
        p!(
            o,
            "{:<10} {:>5} {} {} {} {} {:>10.2} {}",
            r.run_id,
            r.line,
            g(r.measured_g),
            g(r.uncertainty_g),
            g(r.predicted_g),
            g(r.residual_g),
            r.z,
            r.path
        );
    }
    p!(
        o,
        "\nresidual by condition variable (RMS residual per group, g):"
    );
    for v in &c.by_variable {
        let groups: Vec<String> = v
            .groups
            .iter()
            .map(|gr| format!("{} ({}): {:.2e}", gr.label, gr.n, gr.rms_residual_g))
            .collect();
        p!(o, "  {:<12} {}", v.variable, groups.join("; "));
    }
}

pub fn params_text(params: &[crate::fit::FittedParam]) -> String {
    params
        .iter()
        .map(|p| {
            if !p.sigma.is_finite() {
                format!(
                    "{} = {:.6e} (not determined by this table)",
                    p.name, p.value
                )
            } else if crate::fit::asymmetric(p) {
                format!(
                    "{} = {:.6e} -{:.2e} +{:.2e} (profile likelihood; 3 sigma: {:.3e} .. {:.3e})",
                    p.name,
                    p.value,
                    p.sigma_minus,
                    p.sigma_plus,
                    p.value - p.three_sigma_minus,
                    p.value + p.three_sigma_plus
                )
            } else if p.sigma.is_finite() {
                format!("{} = {:.6e} +- {:.2e}", p.name, p.value, p.sigma)
            } else {
                format!(
                    "{} = {:.6e} (not determined by this table)",
                    p.name, p.value
                )
            }
        })
        .collect::<Vec<_>>()
        .join(", ")
}

pub fn write_diagnosis(o: &mut String, d: &Diagnosis) {
    let s = &d.comparison.summary;
    p!(
            o,
        "{}: {}; residual RMS {:.3e} g against a noise floor of {:.3e} g; chi2 per dof {:.4}, p = {:.3e}",
        d.comparison.table, conditions(s), s.rms_residual_g, s.noise_floor_g, s.chi2_per_dof, s.p_value
    );
    p!(
        o,
        "\nwhere the residual goes (weighted quadratic in each variable, F-test):"
    );
    for t in d.trends.iter().take(8) {
        p!(
            o,
            "  {:<12} explains {:>6.1} % of the residual, p = {:.2e} ({} values)",
            t.variable,
            100.0 * t.explained_fraction,
            t.p_value,
            t.distinct_values
        );
    }
    if let Some(l) = &d.lack_of_fit {
        p!(
            o,
            "lack of fit over {} repeated conditions: F = {:.3}, p = {:.3e}; pure error chi2 per dof {:.3}",
            l.repeated_groups, l.f, l.p_value, l.pure_error_chi2_per_dof
        );
    }
    if d.candidates.is_empty() {
        p!(
            o,
            "\ncandidates: not fitted (the model as is passes the chi-square test: nothing to \
             attribute; `lab add EFFECT` fits one on request)"
        );
    } else {
        p!(
            o,
            "\ncandidates, each alone against the model as is, best first (delta BIC < -10: \
             supported):"
        );
    }
    p!(
        o,
        "  {:<24} {:>14} {:>12} {:>12}  parameters",
        "effect",
        "delta_bic",
        "rms_after_g",
        "chi2/dof"
    );
    for c in &d.candidates {
        match &c.fit {
            Some(f) => p!(
                o,
                "  {:<24} {:>14.1} {} {:>12.3}  {}",
                c.kind,
                f.delta_bic,
                g(f.rms_residual_after_g),
                f.chi2_per_dof_after,
                params_text(&f.params_of(&c.kind))
            ),
            None => p!(
                o,
                "  {:<24} not applicable: {}",
                c.kind,
                c.not_applicable.as_deref().unwrap_or("")
            ),
        }
    }
    for n in &d.not_applicable {
        p!(o, "{}", not_applicable_line(n));
    }
    if let Some(c) = d.candidates.iter().find_map(|c| c.fit.as_ref()) {
        for n in &c.not_applicable {
            p!(o, "{}", not_applicable_line(n));
        }
    }
    if d.steps.len() > 1 {
        p!(
            o,
            "\nstepwise search (each step refits all chosen effects jointly; an addition \
             needs delta BIC < {}):",
            d.options.bic_support
        );
        p!(
            o,
            "  {:<28} {:>14} {:>12} {:>10} {:>10}  next best",
            "step",
            "delta_bic",
            "rms_g",
            "chi2/dof",
            "p"
        );
        for st in &d.steps {
            let next: Vec<String> = st
                .runners_up
                .iter()
                .take(2)
                .map(|(k, b)| format!("{k} {b:.1}"))
                .collect();
            p!(
                o,
                "  {:<28} {:>14.1} {} {:>10.3} {:>10.2e}  {}",
                st.action,
                st.delta_bic,
                g(st.rms_residual_g),
                st.chi2_per_dof,
                st.p_value,
                next.join(", ")
            );
        }
    }
    p!(o);
    match &d.verdict {
        Verdict::Noise {
            p_value,
            chi2_per_dof,
        } => p!(
            o,
            "Verdict: the model agrees with the measurements within their uncertainty \
             (chi2 per dof {chi2_per_dof:.3}, p = {p_value:.3}): no effect is missing that this \
             campaign can see."
        ),
        Verdict::Effect {
            kinds,
            delta_bic,
            rms_residual_before_g,
            rms_residual_after_g,
            chi2_per_dof_after,
            physics,
            ..
        } => {
            let what = if kinds.len() > 1 {
                format!("missing effects `{}`", kinds.join("` + `"))
            } else {
                format!("missing effect `{}`", kinds.join(""))
            };
            p!(o, "Verdict: {what} (delta BIC {delta_bic:.1}).");
            if let Some(f) = &d.selected {
                write_fit_params(o, f);
            }
            p!(
                o,
                "  residual RMS {rms_residual_before_g:.3e} g -> {rms_residual_after_g:.3e} g \
                 (chi2 per dof {chi2_per_dof_after:.3}) with {}",
                if kinds.len() > 1 { "them" } else { "it" }
            );
            for ph in physics {
                p!(o, "  physics: {ph}");
            }
            p!(
                o,
                "  add {}: vibrocomp lab add {} --from {} --out model.toml",
                if kinds.len() > 1 { "them" } else { "it" },
                kinds.join(","),
                d.comparison.table
            );
        }
        Verdict::Confounded {
            kinds,
            correlation,
            suggestions,
            found,
        } => {
            if !found.is_empty() {
                p!(o, "Found first: {}.", found.join(", "));
            }
            p!(
                o,
                "Verdict: confounded. {} explain the residual equally well (their fitted VE \
                 changes correlate at {correlation:.4} over this campaign): this campaign \
                 cannot tell them apart.",
                kinds.join(" and ")
            );
            p!(o, "  add conditions where they differ most:");
            for s in suggestions {
                let preds: Vec<String> = s
                    .predictions_g
                    .iter()
                    .map(|(k, v)| format!("{k} {v:.3e} g"))
                    .collect();
                p!(
                    o,
                    "  - {}: {} ({:.0} sigma apart)",
                    s.description,
                    preds.join(", "),
                    s.separation_sigma
                );
            }
        }
        Verdict::Unexplained {
            chi2_per_dof,
            variables,
            best,
            best_explained_fraction,
            found,
            found_explained_fraction,
        } => {
            if found.is_empty() {
                p!(
                    o,
                    "Verdict: unexplained structure (chi2 per dof {chi2_per_dof:.3}): no effect \
                     of the library explains it."
                );
            } else {
                p!(
                    o,
                    "Verdict: found {} (removing {:.1} % of the chi-square), but structure \
                     remains unexplained (chi2 per dof {chi2_per_dof:.3} with {}).",
                    found.join(" + "),
                    100.0 * found_explained_fraction,
                    if found.len() > 1 { "them" } else { "it" }
                );
                if let Some(f) = &d.selected {
                    write_fit_params(o, f);
                }
            }
            if !variables.is_empty() {
                p!(o, "  the residual left follows: {}", variables.join(", "));
            }
            if let Some(b) = best {
                p!(
                    o,
                    "  the best candidate left, {b}, would explain only {:.1} % of it: \
                     not attributed",
                    100.0 * best_explained_fraction
                );
            }
            write_empirical(o, d);
        }
    }
}

/// An empirical correction's terms, the effects refitted beside it or dropped, and
/// what it does to the residual.
pub fn write_correction(o: &mut String, e: &crate::EmpiricalFit) {
    for t in &e.terms {
        p!(
            o,
            "  {:<20} {:>13.6e} +- {:.2e}   ({})",
            t.key,
            t.value,
            t.sigma,
            t.meaning
        );
    }
    if !e.found.is_empty() {
        p!(o, "  beside it, refitted: {}", params_text(&e.found));
    }
    for dropped in &e.dropped {
        p!(o, "  not needed beside it: {dropped}");
    }
    p!(
        o,
        "  cross-validated chi2 {:.1} -> {:.1}; residual RMS {:.3e} g -> {:.3e} g (chi2 per \
         dof {:.3}, p = {:.3})",
        e.cv_chi2_before,
        e.cv_chi2_after,
        e.rms_residual_before_g,
        e.rms_residual_after_g,
        e.chi2_per_dof_after,
        e.p_value_after
    );
}

/// Beyond the library: the empirical correction offered (or why none is).
pub fn write_empirical(o: &mut String, d: &Diagnosis) {
    if let Some(why) = &d.empirical_none {
        p!(o, "Beyond the library: {why}.");
    }
    let Some(e) = &d.empirical else {
        return;
    };
    p!(
        o,
        "Beyond the library: an empirical correction, NOT PHYSICAL (a smooth function of {}, \
         chosen by leave-one-out cross-validation; an extrapolation outside the conditions \
         measured):",
        e.variables.join(", ")
    );
    write_correction(o, e);
    p!(
        o,
        "  add it: vibrocomp lab add empirical --from {} --out model.toml",
        d.comparison.table
    );
}

/// Each effect's parameters on a line, then the correlations beyond 0.5 in size.
pub fn write_fit_params(o: &mut String, f: &crate::EffectFit) {
    for k in &f.kinds {
        p!(o, "  {k}: {}", params_text(&f.params_of(k)));
    }
    let mut strong = Vec::new();
    for i in 0..f.params.len() {
        for j in 0..i {
            let r = f.correlation[i][j];
            if r.abs() > 0.5 {
                strong.push(format!(
                    "{}.{} ~ {}.{} {r:+.3}",
                    f.params[i].effect, f.params[i].name, f.params[j].effect, f.params[j].name
                ));
            }
        }
    }
    if !strong.is_empty() {
        p!(o, "  correlations beyond 0.5: {}", strong.join("; "));
    }
}

/// The rows an effect could not act on, in a line (the first ten named).
pub fn not_applicable_line(n: &crate::fit::NotApplicable) -> String {
    let mut rows: Vec<String> = n
        .rows
        .iter()
        .take(10)
        .map(|(l, r)| format!("line {l} ({r})"))
        .collect();
    if n.rows.len() > 10 {
        rows.push(format!("and {} more", n.rows.len() - 10));
    }
    format!(
        "  {} not evaluated on {} rows: {}: {}",
        n.effect,
        n.rows.len(),
        rows.join(", "),
        n.reason
    )
}

/// The verdict in a few words.
pub fn verdict_line(v: &Verdict) -> String {
    match v {
        Verdict::Noise { chi2_per_dof, .. } => format!("noise, chi2 per dof {chi2_per_dof:.3}"),
        Verdict::Effect { kinds, .. } => format!("effects {}", kinds.join(", ")),
        Verdict::Confounded { kinds, .. } => format!("confounded: {}", kinds.join(", ")),
        Verdict::Unexplained { chi2_per_dof, .. } => {
            format!("unexplained, chi2 per dof {chi2_per_dof:.3}")
        }
    }
}

/// What `lab add` fitted: the effects (jointly) with their parameters, the residual
/// before and after and the rows they could not act on; or the empirical correction
/// (NOT PHYSICAL) with its terms.
pub fn write_added(
    o: &mut String,
    extended: &crate::LabModel,
    table: &std::path::Path,
    fit: Option<&crate::EffectFit>,
    empirical: Option<&crate::EmpiricalFit>,
) {
    if let Some(fit) = fit {
        let before_g = extended
            .fits
            .last()
            .map_or(fit.rms_residual_before_g, |r| r.rms_residual_before_g);
        p!(
            o,
            "{} fitted {}to {} ({} conditions):",
            fit.kinds.join(" + "),
            if fit.kinds.len() > 1 { "jointly " } else { "" },
            table.display(),
            fit.n
        );
        write_fit_params(o, fit);
        p!(
            o,
            "residual RMS {:.3e} g -> {:.3e} g, chi2 per dof {:.4}, delta BIC {:.1}",
            before_g,
            fit.rms_residual_after_g,
            fit.chi2_per_dof_after,
            fit.delta_bic
        );
        for n in &fit.not_applicable {
            p!(o, "{}", not_applicable_line(n));
        }
    }
    if let Some(e) = empirical {
        p!(
            o,
            "empirical correction (NOT PHYSICAL) fitted to {} ({} conditions):",
            table.display(),
            e.n
        );
        write_correction(o, e);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::{FittedParam, NotApplicable};

    fn param(value: f64, sigma: f64, minus: f64, plus: f64) -> FittedParam {
        FittedParam {
            effect: "mount_resonance".into(),
            name: "freq_hz".into(),
            value,
            sigma,
            sigma_minus: minus,
            sigma_plus: plus,
            three_sigma_minus: 3.0 * minus,
            three_sigma_plus: 3.0 * plus,
        }
    }

    #[test]
    fn parameters_read_with_their_uncertainty_or_its_absence() {
        assert_eq!(
            params_text(&[param(48.0, 0.5, 0.5, 0.5)]),
            "freq_hz = 4.800000e1 +- 5.00e-1"
        );
        // A profile interval that is not symmetric: both reaches and the 3 sigma range
        // (48 - 3 * 2 .. 48 + 3 * 4).
        assert_eq!(
            params_text(&[param(48.0, 2.5, 2.0, 4.0)]),
            "freq_hz = 4.800000e1 -2.00e0 +4.00e0 (profile likelihood; 3 sigma: 4.200e1 .. 6.000e1)"
        );
        assert_eq!(
            params_text(&[
                param(48.0, f64::INFINITY, 0.0, 0.0),
                param(1.0, 0.1, 0.1, 0.1)
            ]),
            "freq_hz = 4.800000e1 (not determined by this table), freq_hz = 1.000000e0 +- 1.00e-1"
        );
    }

    #[test]
    fn rows_an_effect_cannot_act_on_name_the_first_ten() {
        let n = NotApplicable {
            effect: "mount_resonance".into(),
            rows: (1..=12).map(|l| (l + 1, format!("r{l}"))).collect(),
            reason: "no spectrum".into(),
        };
        let line = not_applicable_line(&n);
        assert!(line.starts_with("  mount_resonance not evaluated on 12 rows: line 2 (r1), "));
        assert!(
            line.contains("line 11 (r10), and 2 more: no spectrum"),
            "{line}"
        );
        assert!(!line.contains("r11"));
    }

    #[test]
    fn verdicts_in_a_few_words() {
        let v = Verdict::Noise {
            p_value: 0.5,
            chi2_per_dof: 1.0234,
        };
        assert_eq!(verdict_line(&v), "noise, chi2 per dof 1.023");
    }

    #[test]
    fn a_log_summary_is_one_line_with_what_was_left_out() {
        let s = LogTableSummary {
            log: "flight.mcap".into(),
            passports_from: "log".into(),
            units: vec!["AK1".into(), "AK2".into()],
            estimator_window_s: 1.0,
            windows: 39,
            windows_used: 37,
            left_out_flagged: 1,
            left_out_incomplete: 1,
            conditions: 74,
            ..Default::default()
        };
        let mut o = String::new();
        write_log_summary(&mut o, &s);
        assert_eq!(
            o,
            "flight.mcap: 74 conditions from 37 of 39 estimator windows (1 s, units AK1, AK2, \
             passports from log); left out: 1 flagged, 1 incomplete, 0 with aL changing\n"
        );
    }
}
