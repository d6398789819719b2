//! The batch's report: one self-contained HTML page (SVG plots inline, drawn by
//! plotters; no script, no network), built from the results table alone:
//!
//! 1. the published error (`vibration_removed`) of every log and unit, per model (the
//!    points and their quartile box) and per unit (the points coloured by model);
//! 2. the worst runs: the 10 largest published errors, with their log, unit and model;
//! 3. the effects that recur across the batch: for each effect the lab found, the units
//!    it was found in;
//! 4. the parameters' spread over the units: each unit's value with its standard
//!    uncertainty, the median, and the outlier units, more than 3 robust sigmas (the
//!    MAD times 1.4826) from the median, named;
//! 5. the failed jobs with their problem.
//!
//! A batch without lab rows or without compensation rows still renders (its sections
//! say there is nothing to show).

use plotters::prelude::*;
use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;

use crate::manifest::Manifest;
use crate::{Result, Row};

/// The models' colours, in manifest order (then again).
const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(23, 190, 207),
];
/// An outlier unit's point.
const OUTLIER: RGBColor = RGBColor(214, 39, 40);
const BOX: RGBColor = RGBColor(120, 120, 120);
/// Rows of the worst-runs table.
pub const WORST: usize = 10;
/// An outlier is further than this many robust sigmas from the median.
pub const OUTLIER_SIGMAS: f64 = 3.0;
/// Most parameter panels drawn (the table lists them all).
const MAX_PARAM_PLOTS: usize = 24;

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn eng_g(x: f64) -> String {
    vibro_lab::report::eng(x, "g")
}

fn colour(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

fn svg(
    width: u32,
    height: u32,
    draw: impl FnOnce(&DrawingArea<SVGBackend<'_>, plotters::coord::Shift>) -> Result<()>,
) -> Result<String> {
    let mut out = String::new();
    {
        let area = SVGBackend::with_string(&mut out, (width, height)).into_drawing_area();
        area.fill(&WHITE)?;
        draw(&area)?;
        area.present()?;
    }
    Ok(out)
}

/// The label of category `x` on an axis of categories at 0, 1, ...: empty between them.
fn index_label(labels: &[String], x: f64) -> String {
    let i = x.round();
    if (x - i).abs() < 1e-6 && i >= 0.0 {
        labels.get(i as usize).cloned().unwrap_or_default()
    } else {
        String::new()
    }
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let pos = q * (sorted.len() - 1) as f64;
    let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
    sorted[lo] + (sorted[hi] - sorted[lo]) * (pos - lo as f64)
}

fn median(values: &[f64]) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    v.sort_by(f64::total_cmp);
    quantile(&v, 0.5)
}

/// The units more than [`OUTLIER_SIGMAS`] robust sigmas (1.4826 MAD) from the median of
/// `values` (unit, value): the median, the robust sigma, and the outliers' indices.
/// With a MAD of 0 (half the units or more agree exactly) nothing is an outlier.
pub fn outliers(values: &[f64]) -> (f64, f64, Vec<usize>) {
    let m = median(values);
    let deviations: Vec<f64> = values.iter().map(|v| (v - m).abs()).collect();
    let robust_sigma = 1.4826 * median(&deviations);
    let out = if robust_sigma > 0.0 && values.len() >= 3 {
        values
            .iter()
            .enumerate()
            .filter(|(_, v)| (*v - m).abs() > OUTLIER_SIGMAS * robust_sigma)
            .map(|(i, _)| i)
            .collect()
    } else {
        Vec::new()
    };
    (m, robust_sigma, out)
}

/// The page (module docs).
pub fn render_report(manifest: &Manifest, rows: &[Row]) -> Result<String> {
    let mut h = String::new();
    let _ = write!(
        h,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <title>vibrocomp archive: {title}</title>\
         <style>body{{font-family:sans-serif;margin:24px;max-width:1340px;color:#000;background:#fff}}\
         table{{border-collapse:collapse;margin:8px 0 16px}}td,th{{border:1px solid #bbb;padding:3px 8px;text-align:left}}\
         td.n{{text-align:right}}svg{{display:block;margin:8px 0}}</style></head><body>\n\
         <h1>Archive batch</h1><p>Manifest <code>{title}</code>: {logs} logs, {tables} tables, {models} models, {rows} rows.</p>\n",
        title = esc(&manifest.path.display().to_string()),
        logs = manifest.logs.len(),
        tables = manifest.tables.len(),
        models = manifest.models.len(),
        rows = rows.len(),
    );
    let models: Vec<String> = manifest.models.iter().map(|m| m.name.clone()).collect();
    let published: Vec<&Row> = rows
        .iter()
        .filter(|r| r.stage.as_deref() == Some("vibration_removed"))
        .filter(|r| r.error_g.is_some_and(|e| e > 0.0))
        .collect();
    h.push_str("<h2>1. Error after compensation</h2>\n");
    if published.is_empty() {
        h.push_str("<p>No compensation error in this batch.</p>\n");
    } else {
        h.push_str(&format!(
            "<p>The published output's error (<code>vibration_removed</code>, RMS over windows of {}) of every log and unit against the log's reference.</p>\n",
            esc(&format!("{} s", manifest.window_s))
        ));
        h.push_str(&per_model_plot(&published, &models)?);
        h.push_str(&per_unit_plot(&published, &models)?);
        h.push_str(&model_table(&published, &models));
    }
    h.push_str("<h2>2. The worst runs</h2>\n");
    worst_table(&mut h, &published);
    h.push_str("<h2>3. Effects that recur across the batch</h2>\n");
    let lab: Vec<&Row> = rows
        .iter()
        .filter(|r| r.kind == "lab" && r.param.is_none())
        .collect();
    if lab.is_empty() {
        h.push_str("<p>No lab diagnosis in this batch.</p>\n");
    } else {
        let mut by_effect: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
        for r in &lab {
            if let (Some(effects), Some(unit)) = (&r.effect, &r.unit) {
                if r.verdict.as_deref() == Some("effect") {
                    for e in effects.split('+') {
                        by_effect
                            .entry(e.to_string())
                            .or_default()
                            .insert(unit.clone());
                    }
                }
            }
        }
        if by_effect.is_empty() {
            h.push_str("<p>The lab found no effect in any unit.</p>\n");
        } else {
            h.push_str(&effects_plot(&by_effect, lab.len())?);
        }
        verdict_table(&mut h, &lab);
    }
    h.push_str("<h2>4. Parameter spreads and outlier units</h2>\n");
    params_section(&mut h, rows)?;
    h.push_str("<h2>5. Failed jobs</h2>\n");
    let failed: Vec<&Row> = rows
        .iter()
        .filter(|r| {
            r.verdict.as_deref() == Some("failed") || (r.problem.is_some() && r.param.is_none())
        })
        .collect();
    if failed.is_empty() {
        h.push_str("<p>None.</p>\n");
    } else {
        h.push_str("<table><tr><th>job</th><th>log</th><th>unit</th><th>model</th><th>verdict</th><th>problem</th></tr>\n");
        for r in failed {
            let _ = writeln!(
                h,
                "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                esc(&r.job),
                esc(r.log.as_deref().unwrap_or("")),
                esc(r.unit.as_deref().unwrap_or("")),
                esc(r.model.as_deref().unwrap_or("")),
                esc(r.verdict.as_deref().unwrap_or("")),
                esc(r.problem.as_deref().unwrap_or(""))
            );
        }
        h.push_str("</table>\n");
    }
    h.push_str("</body></html>\n");
    Ok(h)
}

fn error_range(rows: &[&Row]) -> (f64, f64) {
    let (lo, hi) = rows
        .iter()
        .filter_map(|r| r.error_g)
        .fold((f64::INFINITY, 0.0f64), |(lo, hi), e| {
            (lo.min(e), hi.max(e))
        });
    (lo / 1.5, hi * 1.5)
}

/// A deterministic spread of the points of one column (no random jitter: the page is
/// the same for the same table).
fn jitter(i: usize) -> f64 {
    ((i * 37) % 17) as f64 / 17.0 * 0.36 - 0.18
}

fn per_model_plot(rows: &[&Row], models: &[String]) -> Result<String> {
    let (lo, hi) = error_range(rows);
    let n = models.len().max(1);
    let labels = models.to_vec();
    svg(1320, 380, |area| {
        let mut chart = ChartBuilder::on(area)
            .caption(
                "published error per model (points: logs x units; box: quartiles and median)",
                ("sans-serif", 16),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(80)
            .build_cartesian_2d(-0.5f64..(n as f64 - 0.5), (lo..hi).log_scale())?;
        chart
            .configure_mesh()
            .x_labels(n + 1)
            .x_label_formatter(&|x| index_label(&labels, *x))
            .y_label_formatter(&|y| eng_g(*y))
            .y_desc("RMS error")
            .draw()?;
        for (m, name) in models.iter().enumerate() {
            let mut values: Vec<f64> = rows
                .iter()
                .filter(|r| r.model.as_deref() == Some(name))
                .filter_map(|r| r.error_g)
                .collect();
            values.sort_by(f64::total_cmp);
            if values.is_empty() {
                continue;
            }
            let x = m as f64;
            let (q1, q2, q3) = (
                quantile(&values, 0.25),
                quantile(&values, 0.5),
                quantile(&values, 0.75),
            );
            chart.draw_series(std::iter::once(Rectangle::new(
                [(x - 0.3, q1), (x + 0.3, q3)],
                BOX.stroke_width(2),
            )))?;
            chart.draw_series(std::iter::once(PathElement::new(
                vec![(x - 0.3, q2), (x + 0.3, q2)],
                BOX.stroke_width(3),
            )))?;
            chart.draw_series(
                values
                    .iter()
                    .enumerate()
                    .map(|(i, v)| Circle::new((x + jitter(i), *v), 4, colour(m).filled())),
            )?;
        }
        Ok(())
    })
}

fn per_unit_plot(rows: &[&Row], models: &[String]) -> Result<String> {
    let (lo, hi) = error_range(rows);
    let mut units: Vec<String> = Vec::new();
    for r in rows {
        if let Some(u) = &r.unit {
            if !units.contains(u) {
                units.push(u.clone());
            }
        }
    }
    let n = units.len().max(1);
    let labels = units.clone();
    let width = (200 + 60 * n as u32).clamp(700, 1320);
    svg(width, 380, |area| {
        let mut chart = ChartBuilder::on(area)
            .caption(
                "published error per unit (colour: model)",
                ("sans-serif", 16),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(80)
            .build_cartesian_2d(-0.5f64..(n as f64 - 0.5), (lo..hi).log_scale())?;
        chart
            .configure_mesh()
            .x_labels((n + 1).min(40))
            .x_label_formatter(&|x| index_label(&labels, *x))
            .y_label_formatter(&|y| eng_g(*y))
            .y_desc("RMS error")
            .draw()?;
        for (m, name) in models.iter().enumerate() {
            let points: Vec<(f64, f64)> = rows
                .iter()
                .filter(|r| r.model.as_deref() == Some(name))
                .filter_map(|r| {
                    let u = units.iter().position(|u| Some(u) == r.unit.as_ref())?;
                    Some((
                        u as f64 + (m as f64 - (models.len() as f64 - 1.0) / 2.0) * 0.12,
                        r.error_g?,
                    ))
                })
                .collect();
            chart
                .draw_series(
                    points
                        .iter()
                        .map(|p| Circle::new(*p, 4, colour(m).filled())),
                )?
                .label(name.clone())
                .legend(move |(x, y)| Circle::new((x, y), 4, colour(m).filled()));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
        Ok(())
    })
}

fn model_table(rows: &[&Row], models: &[String]) -> String {
    let mut h = String::from(
        "<table><tr><th>model</th><th>log x unit</th><th>median</th><th>worst</th></tr>\n",
    );
    for name in models {
        let v: Vec<f64> = rows
            .iter()
            .filter(|r| r.model.as_deref() == Some(name))
            .filter_map(|r| r.error_g)
            .collect();
        let worst = v.iter().copied().fold(f64::NAN, f64::max);
        let _ = writeln!(
            h,
            "<tr><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td></tr>",
            esc(name),
            v.len(),
            eng_g(median(&v)),
            eng_g(worst)
        );
    }
    h.push_str("</table>\n");
    h
}

fn worst_table(h: &mut String, rows: &[&Row]) {
    if rows.is_empty() {
        h.push_str("<p>No compensation error in this batch.</p>\n");
        return;
    }
    let mut sorted: Vec<&&Row> = rows.iter().collect();
    sorted.sort_by(|a, b| {
        b.error_g
            .unwrap_or(0.0)
            .total_cmp(&a.error_g.unwrap_or(0.0))
            .then_with(|| a.job.cmp(&b.job))
    });
    h.push_str("<table><tr><th>#</th><th>error (vibration removed)</th><th>log</th><th>unit</th><th>model</th><th>windows</th></tr>\n");
    for (i, r) in sorted.iter().take(WORST).enumerate() {
        let _ = writeln!(
            h,
            "<tr><td class=\"n\">{}</td><td class=\"n\">{}</td><td>{}</td><td>{}</td><td>{}</td><td class=\"n\">{}</td></tr>",
            i + 1,
            eng_g(r.error_g.unwrap_or(f64::NAN)),
            esc(r.log.as_deref().unwrap_or("")),
            esc(r.unit.as_deref().unwrap_or("")),
            esc(r.model.as_deref().unwrap_or("")),
            r.windows.map_or_else(String::new, |w| w.to_string())
        );
    }
    h.push_str("</table>\n");
}

fn effects_plot(by_effect: &BTreeMap<String, BTreeSet<String>>, units: usize) -> Result<String> {
    let mut bars: Vec<(&String, usize)> = by_effect.iter().map(|(k, v)| (k, v.len())).collect();
    bars.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(b.0)));
    let n = bars.len();
    let svg_text = svg(1320, 90 + 30 * n as u32, |area| {
        let mut chart = ChartBuilder::on(area)
            .caption(
                format!("units (of {units} diagnosed) in which the lab found each effect"),
                ("sans-serif", 16),
            )
            .margin(12)
            .x_label_area_size(36)
            .y_label_area_size(10)
            .build_cartesian_2d(0.0..(units.max(1) as f64 * 1.25), 0.0..n as f64)?;
        chart
            .configure_mesh()
            .disable_y_mesh()
            .disable_y_axis()
            .x_desc("units")
            .draw()?;
        for (i, (kind, count)) in bars.iter().enumerate() {
            let y = (n - 1 - i) as f64;
            chart.draw_series(std::iter::once(Rectangle::new(
                [(0.0, y + 0.15), (*count as f64, y + 0.85)],
                colour(2).filled(),
            )))?;
            chart.draw_series(std::iter::once(Text::new(
                format!("{kind}: {count}"),
                (*count as f64 + 0.05, y + 0.7),
                ("sans-serif", 14).into_font(),
            )))?;
        }
        Ok(())
    })?;
    let mut h = svg_text;
    h.push_str("<table><tr><th>effect</th><th>units</th><th>which</th></tr>\n");
    for (kind, count) in &bars {
        let which: Vec<String> = by_effect[*kind].iter().map(|u| esc(u)).collect();
        let _ = writeln!(
            h,
            "<tr><td>{}</td><td class=\"n\">{count}</td><td>{}</td></tr>",
            esc(kind),
            which.join(", ")
        );
    }
    h.push_str("</table>\n");
    Ok(h)
}

fn verdict_table(h: &mut String, lab: &[&Row]) {
    h.push_str("<table><tr><th>unit</th><th>verdict</th><th>effects</th><th>residual RMS (model as is)</th><th>windows/rows</th><th>problem</th></tr>\n");
    for r in lab {
        let _ = writeln!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td>{}</td></tr>",
            esc(r.unit.as_deref().unwrap_or("")),
            esc(r.verdict.as_deref().unwrap_or("")),
            esc(r.effect.as_deref().unwrap_or("")),
            r.error_g.map_or_else(String::new, eng_g),
            r.windows.map_or_else(String::new, |w| w.to_string()),
            esc(r.problem.as_deref().unwrap_or(""))
        );
    }
    h.push_str("</table>\n");
}

/// One effect parameter over the units: (unit, value, sigma).
type Spread = Vec<(String, f64, Option<f64>)>;

fn params_section(h: &mut String, rows: &[Row]) -> Result<()> {
    let mut spreads: BTreeMap<(String, String), Spread> = BTreeMap::new();
    for r in rows.iter().filter(|r| r.kind == "lab") {
        if let (Some(e), Some(p), Some(u), Some(v)) = (&r.effect, &r.param, &r.unit, r.value) {
            spreads
                .entry((e.clone(), p.clone()))
                .or_default()
                .push((u.clone(), v, r.sigma));
        }
    }
    if spreads.is_empty() {
        h.push_str("<p>No effect parameter was fitted in this batch.</p>\n");
        return Ok(());
    }
    h.push_str("<table><tr><th>effect</th><th>parameter</th><th>units</th><th>median</th><th>robust sigma (1.4826 MAD)</th><th>outlier units (&gt; 3 robust sigmas)</th></tr>\n");
    let mut plots = String::new();
    for (i, ((effect, param), values)) in spreads.iter().enumerate() {
        let v: Vec<f64> = values.iter().map(|x| x.1).collect();
        let (m, rs, out) = outliers(&v);
        let names: Vec<String> = out
            .iter()
            .map(|&k| {
                format!(
                    "{} ({})",
                    esc(&values[k].0),
                    vibro_lab::report::eng(values[k].1, "")
                )
            })
            .collect();
        let _ = writeln!(
            h,
            "<tr><td>{}</td><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td>{}</td></tr>",
            esc(effect),
            esc(param),
            values.len(),
            vibro_lab::report::eng(m, ""),
            vibro_lab::report::eng(rs, ""),
            if names.is_empty() { "none".into() } else { names.join(", ") }
        );
        if i < MAX_PARAM_PLOTS {
            plots.push_str(&param_plot(effect, param, values, m, rs, &out)?);
        }
    }
    h.push_str("</table>\n");
    h.push_str(&plots);
    Ok(())
}

/// A tick of a parameter's axis over `lo..hi`: as many significant digits as the span
/// needs to tell the ticks apart (a spread of 1e-5 around 47.29 needs 7).
fn tick(y: f64, lo: f64, hi: f64) -> String {
    let span = (hi - lo).abs().max(f64::MIN_POSITIVE);
    let size = lo.abs().max(hi.abs()).max(span);
    let digits = ((size / span).log10().ceil() as usize + 2).clamp(3, 12);
    format!("{:.*e}", digits - 1, y)
}

fn param_plot(
    effect: &str,
    param: &str,
    values: &Spread,
    m: f64,
    rs: f64,
    out: &[usize],
) -> Result<String> {
    let n = values.len();
    let lo_hi = values.iter().flat_map(|(_, v, s)| {
        let s = s.unwrap_or(0.0);
        [v - s, v + s]
    });
    let (mut lo, mut hi) = lo_hi.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
        (a.min(x), b.max(x))
    });
    if rs > 0.0 {
        lo = lo.min(m - OUTLIER_SIGMAS * rs);
        hi = hi.max(m + OUTLIER_SIGMAS * rs);
    }
    let pad = ((hi - lo) * 0.1)
        .max(hi.abs().max(lo.abs()) * 1e-3)
        .max(1e-300);
    let (lo, hi) = (lo - pad, hi + pad);
    let labels: Vec<String> = values.iter().map(|v| v.0.clone()).collect();
    svg(1320, 300, |area| {
        let mut chart = ChartBuilder::on(area)
            .caption(
                format!("{effect}.{param} per unit (value +/- sigma; line: median; band: 3 robust sigmas; red: outlier)"),
                ("sans-serif", 15),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(90)
            .build_cartesian_2d(-0.5f64..(n as f64 - 0.5), lo..hi)?;
        chart
            .configure_mesh()
            .x_labels((n + 1).min(40))
            .x_label_formatter(&|x| index_label(&labels, *x))
            .y_label_formatter(&|y| tick(*y, lo, hi))
            .draw()?;
        if rs > 0.0 {
            chart.draw_series(std::iter::once(Rectangle::new(
                [
                    (-0.5, m - OUTLIER_SIGMAS * rs),
                    (n as f64 - 0.5, m + OUTLIER_SIGMAS * rs),
                ],
                colour(2).mix(0.2).filled(),
            )))?;
        }
        chart.draw_series(std::iter::once(PathElement::new(
            vec![(-0.5, m), (n as f64 - 0.5, m)],
            BOX.stroke_width(2),
        )))?;
        for (i, (_, v, s)) in values.iter().enumerate() {
            let c = if out.contains(&i) { OUTLIER } else { colour(0) };
            if let Some(s) = s {
                chart.draw_series(std::iter::once(ErrorBar::new_vertical(
                    i as f64,
                    v - s,
                    *v,
                    v + s,
                    c.stroke_width(2),
                    10,
                )))?;
            }
            chart.draw_series(std::iter::once(Circle::new((i as f64, *v), 5, c.filled())))?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_outlier_is_three_robust_sigmas_from_the_median() {
        let (m, rs, out) = outliers(&[1.0, 1.1, 0.9, 1.05, 0.95, 5.0]);
        assert!((m - 1.025).abs() < 1e-12, "{m}");
        assert!(rs > 0.0);
        assert_eq!(out, [5]);
        // Agreeing units: no outlier, and a MAD of 0 names none.
        assert!(outliers(&[2.0, 2.0, 2.0, 3.0]).2.is_empty());
        assert!(outliers(&[1.0, 100.0]).2.is_empty());
    }

    #[test]
    fn a_batch_without_lab_rows_or_without_errors_still_renders() {
        let m = crate::Manifest {
            path: "/m.toml".into(),
            window_s: 0.5,
            triad: "default".into(),
            keep_sessions: false,
            lab: crate::manifest::LabSettings {
                enabled: true,
                max_effects: 2,
                effects: Vec::new(),
                model: None,
                estimator_config: None,
            },
            models: vec![crate::manifest::ModelSpec {
                name: "a<b".into(),
                estimator_config: None,
                compensator_config: None,
                model: None,
            }],
            logs: Vec::new(),
            tables: Vec::new(),
        };
        let html = render_report(&m, &[]).unwrap();
        assert!(html.contains("No compensation error") && html.contains("No lab diagnosis"));
        let row = |unit: &str, e: f64| Row {
            job: "compensate/0/a<b".into(),
            kind: "compensate".into(),
            log: Some("l.mcap".into()),
            unit: Some(unit.into()),
            model: Some("a<b".into()),
            stage: Some("vibration_removed".into()),
            error_g: Some(e),
            verdict: Some("ok".into()),
            ..Row::default()
        };
        let p = |unit: &str, v: f64| Row {
            job: format!("lab/{unit}"),
            kind: "lab".into(),
            unit: Some(unit.into()),
            stage: Some("lab".into()),
            verdict: Some("effect".into()),
            effect: Some("k".into()),
            param: Some("p".into()),
            value: Some(v),
            sigma: Some(0.01),
            ..Row::default()
        };
        let rows = vec![
            row("U1", 1e-4),
            row("U2", 3e-4),
            p("U1", 1.0),
            p("U2", 1.1),
            p("U3", 0.9),
            p("U4", 1.0),
            p("U9", 9.0),
        ];
        let html = render_report(&m, &rows).unwrap();
        assert!(
            html.contains("a&lt;b") && !html.contains("<td>a<b"),
            "escaped"
        );
        assert!(html.matches("<svg").count() >= 3);
        assert!(html.contains("U9 (9.00)"), "the outlier named");
    }
}
