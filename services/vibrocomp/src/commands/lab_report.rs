//! `vibrocomp lab report`: a self-contained HTML report of the lab's diagnosis, with
//! SVG plots drawn by plotters (inline, so the one file opens anywhere without network
//! or scripts):
//!
//! - the residual against each condition variable, before (the model as given) and
//!   after (the model with the effects the lab adds, one at a time, while one is
//!   supported), with the uncertainty bars;
//! - the candidates' ranking (minus delta BIC, log scale);
//! - the residual RMS falling as effects are added;
//! - the diagnosis in words and the comparison's numbers.

use plotters::coord::Shift;
use plotters::prelude::*;
use std::fmt::Write as _;
use std::path::Path;
use vibro_lab::diagnose::{Diagnosis, LadderStep};
use vibro_lab::{CampaignTable, Comparison, LabModel};

/// Colour of the points before (the model as given) and after.
pub const BEFORE: RGBColor = RGBColor(214, 39, 40);
pub const AFTER: RGBColor = RGBColor(31, 119, 180);

type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

fn svg(
    width: u32,
    height: u32,
    draw: impl FnOnce(&Area<'_>) -> anyhow::Result<()>,
) -> anyhow::Result<String> {
    let mut out = String::new();
    {
        let area = SVGBackend::with_string(&mut out, (width, height)).into_drawing_area();
        area.fill(&WHITE)?;
        draw(&area)?;
        area.present()?;
    }
    Ok(out)
}

fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    if !lo.is_finite() {
        return (-1.0, 1.0);
    }
    let pad = ((hi - lo) * 0.08)
        .max(hi.abs().max(lo.abs()) * 1e-3)
        .max(1e-12);
    (lo - pad, hi + pad)
}

/// Residual (ug) against one variable, before and after.
fn residual_plot(
    variable: &str,
    table: &CampaignTable,
    before: &Comparison,
    after: &Comparison,
) -> anyhow::Result<String> {
    let xs = table
        .variable_column(variable)
        .ok_or_else(|| anyhow::anyhow!("no variable {variable}"))?;
    let pts = |c: &Comparison| -> Vec<(f64, f64, f64)> {
        xs.iter()
            .zip(&c.rows)
            .filter(|(x, _)| x.is_finite())
            .map(|(x, r)| (*x, r.residual_g * 1e6, r.uncertainty_g * 1e6))
            .collect()
    };
    let (b, a) = (pts(before), pts(after));
    let (x0, x1) = range(b.iter().map(|p| p.0));
    let (y0, y1) = range(b.iter().chain(&a).flat_map(|p| [p.1 - p.2, p.1 + p.2]));
    svg(640, 360, |area| {
        let mut chart = ChartBuilder::on(area)
            .caption(format!("residual against {variable}"), ("sans-serif", 18))
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart
            .configure_mesh()
            .x_desc(variable)
            .y_desc("residual, ug")
            .draw()?;
        for (pts, colour, label) in [(&b, BEFORE, "before"), (&a, AFTER, "after")] {
            chart.draw_series(pts.iter().map(|&(x, y, u)| {
                ErrorBar::new_vertical(x, y - u, y, y + u, colour.filled(), 6)
            }))?;
            chart
                .draw_series(
                    pts.iter()
                        .map(|&(x, y, _)| Circle::new((x, y), 4, colour.filled())),
                )?
                .label(label)
                .legend(move |(x, y)| Circle::new((x, y), 4, colour.filled()));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
        Ok(())
    })
}

/// Candidates ranked: `log10(-delta BIC)` per candidate (0 when not supported).
fn ranking_plot(d: &Diagnosis) -> anyhow::Result<String> {
    let bars: Vec<(String, f64, bool)> = d
        .candidates
        .iter()
        .map(|c| {
            let v = c
                .fit
                .as_ref()
                .map_or(0.0, |f| (-f.delta_bic).max(1.0).log10());
            (c.kind.clone(), v, c.supported)
        })
        .collect();
    let n = bars.len().max(1);
    let xmax = bars.iter().map(|b| b.1).fold(1.0, f64::max) * 1.35;
    svg(640, 40 + 34 * n as u32 + 60, |area| {
        let mut chart = ChartBuilder::on(area)
            .caption(
                "candidates: log10(-delta BIC), supported beyond 1 (delta BIC < -10)",
                ("sans-serif", 16),
            )
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(10)
            .build_cartesian_2d(0.0..xmax, 0.0..n as f64)?;
        chart
            .configure_mesh()
            .disable_y_mesh()
            .disable_y_axis()
            .x_desc("log10(-delta BIC)")
            .draw()?;
        for (i, (kind, v, supported)) in bars.iter().enumerate() {
            let y = (n - 1 - i) as f64;
            let colour = if *supported {
                AFTER
            } else {
                RGBColor(170, 170, 170)
            };
            chart.draw_series(std::iter::once(Rectangle::new(
                [(0.0, y + 0.15), (*v, y + 0.85)],
                colour.filled(),
            )))?;
            chart.draw_series(std::iter::once(Text::new(
                format!("{kind} {v:.1}"),
                (v + xmax * 0.01, y + 0.62),
                ("sans-serif", 14),
            )))?;
        }
        Ok(())
    })
}

/// The residual RMS (ug, log scale) at each step of the ladder.
fn ladder_plot(steps: &[LadderStep], noise_floor_g: f64) -> anyhow::Result<String> {
    let ys: Vec<f64> = steps
        .iter()
        .map(|s| (s.rms_residual_g * 1e6).max(1e-9))
        .collect();
    let floor = noise_floor_g * 1e6;
    let lo = ys.iter().copied().fold(floor, f64::min) / 3.0;
    let hi = ys.iter().copied().fold(floor, f64::max) * 3.0;
    let n = steps.len().max(2);
    svg(640, 360, |area| {
        let mut chart = ChartBuilder::on(area)
            .caption("residual RMS as effects are added", ("sans-serif", 18))
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(70)
            .build_cartesian_2d(-0.3..(n as f64 - 0.7), (lo..hi).log_scale())?;
        chart
            .configure_mesh()
            .x_labels(n)
            .x_label_formatter(&|x| {
                let i = x.round() as usize;
                if (x - i as f64).abs() > 0.01 {
                    return String::new();
                }
                match steps.get(i) {
                    Some(s) if s.effects.is_empty() => "model as given".into(),
                    Some(s) => format!("+ {}", s.effects.last().map_or("", String::as_str)),
                    None => String::new(),
                }
            })
            .y_desc("residual RMS, ug")
            .draw()?;
        chart.draw_series(LineSeries::new(
            ys.iter().enumerate().map(|(i, y)| (i as f64, *y)),
            AFTER.stroke_width(2),
        ))?;
        chart.draw_series(
            ys.iter()
                .enumerate()
                .map(|(i, y)| Circle::new((i as f64, *y), 5, AFTER.filled())),
        )?;
        chart
            .draw_series(LineSeries::new(
                [(-0.3, floor), (n as f64 - 0.7, floor)],
                BLACK.mix(0.5).stroke_width(1),
            ))?
            .label("noise floor")
            .legend(|(x, y)| PathElement::new([(x, y), (x + 16, y)], BLACK));
        chart
            .configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE)
            .draw()?;
        Ok(())
    })
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// What the report holds, for `--json`.
#[derive(serde::Serialize)]
pub struct ReportSummary {
    pub html: String,
    pub plots: usize,
    pub ladder: Vec<LadderStep>,
    pub rms_before_g: f64,
    pub rms_after_g: f64,
    pub effects_added: Vec<String>,
}

/// What the report shows.
pub struct ReportInput<'a> {
    pub table: &'a CampaignTable,
    /// The model as given.
    pub model: &'a LabModel,
    /// Its diagnosis, and the diagnosis as text.
    pub diagnosis: &'a Diagnosis,
    pub diagnosis_text: &'a str,
    /// The steps of the lab adding effects, and the model they end with.
    pub ladder: &'a [LadderStep],
    pub final_model: &'a LabModel,
    /// The comparison of the final model.
    pub after: &'a Comparison,
}

/// Writes `dir/index.html` (and each plot as an SVG file beside it).
pub fn write(dir: &Path, r: &ReportInput<'_>) -> anyhow::Result<ReportSummary> {
    let ReportInput {
        table,
        model,
        diagnosis,
        diagnosis_text,
        ladder,
        final_model,
        after,
    } = *r;
    std::fs::create_dir_all(dir)
        .map_err(|e| anyhow::anyhow!("{}: cannot create: {e}", dir.display()))?;
    let before = &diagnosis.comparison;
    // The variables: the trends' order (strongest first), then the tone frequency and
    // aL3 if not already there, at most 6.
    let mut variables: Vec<String> = diagnosis
        .trends
        .iter()
        .map(|t| t.variable.clone())
        .collect();
    for v in ["freq_hz", "aL3_g", "aB3_g"] {
        if !variables.iter().any(|x| x == v) {
            variables.push(v.into());
        }
    }
    let columns = table.variable_columns();
    variables.retain(|v| {
        columns
            .iter()
            .any(|(n, xs)| n == v && xs.iter().any(|x| x.is_finite()))
    });
    variables.truncate(6);
    let mut plots: Vec<(String, String)> = Vec::new();
    for v in &variables {
        plots.push((
            format!("residual-{v}.svg"),
            residual_plot(v, table, before, after)?,
        ));
    }
    plots.push(("ranking.svg".into(), ranking_plot(diagnosis)?));
    plots.push((
        "ladder.svg".into(),
        ladder_plot(ladder, before.summary.noise_floor_g)?,
    ));
    for (name, text) in &plots {
        std::fs::write(dir.join(name), text)
            .map_err(|e| anyhow::anyhow!("{}: {e}", dir.join(name).display()))?;
    }
    let mut h = String::new();
    let s = &before.summary;
    let effects_added: Vec<String> = final_model.effect_kinds()[model.effects.len()..].to_vec();
    let _ = write!(
        h,
        "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>vibrocomp lab report: {}</title>\
         <style>body{{font-family:sans-serif;margin:24px;max-width:1340px}}\
         table{{border-collapse:collapse}}td,th{{border:1px solid #bbb;padding:3px 8px;text-align:right}}\
         .plots{{display:flex;flex-wrap:wrap;gap:8px}}pre{{background:#f6f6f6;padding:8px;overflow-x:auto}}</style>\
         </head><body><h1>vibrocomp lab report</h1>",
        esc(&before.table)
    );
    let _ = write!(
        h,
        "<p>Campaign <b>{}</b>: {} conditions. Model: {} mode, effects: {}. Effects added by the lab: {}.</p>",
        esc(&before.table),
        s.n,
        esc(&before.mode),
        esc(&if before.effects.is_empty() { "none".into() } else { before.effects.join(", ") }),
        esc(&if effects_added.is_empty() { "none".into() } else { effects_added.join(", ") }),
    );
    let _ = write!(
        h,
        "<table><tr><th></th><th>residual RMS, g</th><th>max |residual|, g</th><th>chi2 per dof</th><th>p-value</th></tr>\
         <tr><th>before</th><td>{:.4e}</td><td>{:.4e}</td><td>{:.4}</td><td>{:.3e}</td></tr>\
         <tr><th>after</th><td>{:.4e}</td><td>{:.4e}</td><td>{:.4}</td><td>{:.3e}</td></tr>\
         <tr><th>noise floor</th><td>{:.4e}</td><td></td><td></td><td></td></tr></table>",
        s.rms_residual_g,
        s.max_abs_residual_g,
        s.chi2_per_dof,
        s.p_value,
        after.summary.rms_residual_g,
        after.summary.max_abs_residual_g,
        after.summary.chi2_per_dof,
        after.summary.p_value,
        s.noise_floor_g
    );
    h.push_str("<h2>Residual against each variable (red: model as given, blue: with the effects added)</h2><div class=\"plots\">");
    for (_, text) in &plots[..variables.len()] {
        h.push_str(text);
    }
    h.push_str("</div><h2>Which effect is missing</h2><div class=\"plots\">");
    for (_, text) in &plots[variables.len()..] {
        h.push_str(text);
    }
    let _ = write!(
        h,
        "</div><h2>Diagnosis</h2><pre>{}</pre>",
        esc(diagnosis_text)
    );
    h.push_str("<h2>The error as effects are added</h2><table><tr><th>effects</th><th>residual RMS, g</th><th>chi2 per dof</th></tr>");
    for st in ladder {
        let _ = write!(
            h,
            "<tr><td style=\"text-align:left\">{}</td><td>{:.4e}</td><td>{:.4}</td></tr>",
            esc(&if st.effects.is_empty() {
                "model as given".into()
            } else {
                st.effects.join(" + ")
            }),
            st.rms_residual_g,
            st.chi2_per_dof
        );
    }
    h.push_str("</table></body></html>\n");
    let html = dir.join("index.html");
    std::fs::write(&html, &h).map_err(|e| anyhow::anyhow!("{}: {e}", html.display()))?;
    Ok(ReportSummary {
        html: html.display().to_string(),
        plots: plots.len(),
        ladder: ladder.to_vec(),
        rms_before_g: s.rms_residual_g,
        rms_after_g: after.summary.rms_residual_g,
        effects_added,
    })
}
