//! The lab's report: a self-contained HTML report of the lab's diagnosis, with
//! SVG plots drawn by plotters (inline, so the one file opens anywhere without network
//! or scripts), laid out for a test engineer to read at a glance:
//!
//! - the verdict in words, and the residual before and after in a table;
//! - the residual against each condition variable in two panels side by side, before
//!   (the model as given, red) and after (with the effects the lab found, blue), each
//!   on its own scale (the residual before is often milli-g and after nano-g: a shared
//!   linear axis would hide the after), with the uncertainty bars and a band of plus
//!   or minus the noise floor (green);
//! - for MCAP logs (variables `t_s` and `unit`), the residual against time, per unit,
//!   before and after;
//! - the stepwise search ([`Diagnosis::steps`]): the residual RMS at each step (log
//!   scale) against the noise floor, and its table;
//! - the final joint fit ([`Diagnosis::selected`]): parameters with their
//!   uncertainties and their correlation matrix;
//! - the candidates' first round (minus delta BIC, log scale) and the diagnosis text.
//!
//! Numbers are in engineering form (`1.20 mg`, `35.0 ng`, `48.0 Hz`).
//!
//! [`render`] draws the page and its plots in memory; the caller (`vibrocomp lab
//! report`) writes them: each plot as an SVG file beside `index.html`, `index.html`
//! last, since its presence marks a complete report ([`REPORT_FILES`]).

use crate::diagnose::{Diagnosis, LadderStep, Step, Verdict};
use crate::{CampaignTable, Comparison, EffectFit, Error, LabModel, Result};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::fmt::Write as _;

/// Colour of the points before (the model as given) and after.
pub const BEFORE: RGBColor = RGBColor(214, 39, 40);
pub const AFTER: RGBColor = RGBColor(31, 119, 180);
/// The band of plus or minus the noise floor.
pub const FLOOR_BAND: RGBColor = RGBColor(199, 233, 192);
/// The candidates' bars (supported, not supported): neither red nor blue, so that
/// those colours stay the residual points'.
pub(crate) const SUPPORTED: RGBColor = RGBColor(44, 160, 44);
pub(crate) const NOT_SUPPORTED: RGBColor = RGBColor(180, 180, 180);
pub(crate) const GREY: RGBColor = RGBColor(120, 120, 120);

/// Panel size: two side by side fill the page's 1340 px.
pub(crate) const PANEL: (u32, u32) = (660, 300);

pub(crate) type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

pub(crate) fn svg(
    width: u32,
    height: u32,
    draw: impl FnOnce(&Area<'_>) -> Result<()>,
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

const PREFIXES: [(i32, &str); 10] = [
    (-15, "f"),
    (-12, "p"),
    (-9, "n"),
    (-6, "µ"),
    (-3, "m"),
    (0, ""),
    (3, "k"),
    (6, "M"),
    (9, "G"),
    (12, "T"),
];

/// The power of 1000 to write `x` with: its engineering exponent, within the
/// prefixes, and none for units that take no prefix (degrees, seconds beyond 1).
fn eng_exponent(x: f64, unit: &str) -> i32 {
    if unit == "deg" || unit.is_empty() || x == 0.0 || !x.is_finite() {
        return 0;
    }
    let e = (x.abs().log10() / 3.0).floor() as i32 * 3;
    let e = e.clamp(-15, 12);
    if unit == "s" {
        e.min(0)
    } else {
        e
    }
}

fn prefix(e: i32) -> &'static str {
    PREFIXES
        .iter()
        .find(|(p, _)| *p == e)
        .map_or("", |(_, s)| s)
}

/// `x` in engineering form with 3 significant digits: `1.20 mg`, `35.0 ng`, `48.0 Hz`.
pub fn eng(x: f64, unit: &str) -> String {
    if !x.is_finite() {
        return "n/a".into();
    }
    if x == 0.0 {
        return format!("0 {unit}").trim_end().to_string();
    }
    // The mantissa rounded to 3 significant digits, so that 1e-7 is `100 ng`, not
    // `100.0 ng` from 99.999..., and 999.7e-9 is `1.00 µg`.
    let round3 = |m: f64| format!("{m:.2e}").parse::<f64>().unwrap_or(m);
    let mut e = eng_exponent(x, unit);
    let mut m = round3(x / 10f64.powi(e));
    if m.abs() >= 1000.0 && eng_exponent(1e3 * 10f64.powi(e), unit) > e {
        e += 3;
        m = round3(m / 1e3);
    }
    let digits = if m.abs() >= 100.0 {
        0
    } else if m.abs() >= 10.0 {
        1
    } else {
        2
    };
    format!("{m:.digits$} {}{unit}", prefix(e))
        .trim_end()
        .to_string()
}

/// A tick formatter for a linear axis over `lo..hi`: one prefix for the whole axis
/// (`-1.0 mg, -0.5 mg, 0, 0.5 mg`), the decimals its tick step needs.
pub(crate) fn axis_formatter(lo: f64, hi: f64, unit: &str) -> impl Fn(&f64) -> String {
    let e = eng_exponent(lo.abs().max(hi.abs()), unit);
    let scale = 10f64.powi(e);
    let step = ((hi - lo) / 8.0 / scale).abs().max(1e-300);
    let decimals = (-step.log10().floor()).clamp(0.0, 6.0) as usize;
    let unit = format!("{}{unit}", prefix(e));
    move |v: &f64| {
        let m = v / scale;
        if m.abs() < 0.5 * 10f64.powi(-(decimals as i32)) {
            "0".into()
        } else {
            format!("{m:.decimals$} {unit}").trim_end().to_string()
        }
    }
}

/// A variable's axis title and unit: `freq_hz` is (`frequency, Hz`, `Hz`).
fn describe(variable: &str) -> (String, &'static str) {
    let named = |what: &str, unit: &'static str| {
        let title = if unit.is_empty() {
            what.to_string()
        } else {
            format!("{what}, {unit}")
        };
        (title, unit)
    };
    match variable {
        "freq_hz" => named("frequency", "Hz"),
        "aL1_g" | "aL2_g" | "aL3_g" => {
            named(&format!("flight acceleration {}", &variable[..3]), "g")
        }
        "aB1_g" | "aB2_g" | "aB3_g" => named(&format!("tone amplitude {}", &variable[..3]), "g"),
        "sigma1_g" | "sigma2_g" | "sigma3_g" => {
            named(&format!("random vibration RMS {}", &variable[..6]), "g")
        }
        "phase31_deg" | "phase32_deg" => named(&format!("phase {}", &variable[5..7]), "deg"),
        "t_s" => named("time since the log's first sample", "s"),
        "vibrating_s" => named("time vibrating", "s"),
        v => {
            for (suffix, unit) in [("_g", "g"), ("_hz", "Hz"), ("_s", "s"), ("_deg", "deg")] {
                if let Some(stem) = v.strip_suffix(suffix) {
                    return named(stem, unit);
                }
            }
            named(v, "")
        }
    }
}

pub(crate) fn finite_range(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    lo.is_finite().then_some((lo, hi))
}

/// An axis range around `lo..hi` with 6 % margins (and some width when it has none).
pub(crate) fn padded(lo: f64, hi: f64) -> (f64, f64) {
    let pad = ((hi - lo) * 0.06)
        .max(hi.abs().max(lo.abs()) * 1e-3)
        .max(1e-15);
    (lo - pad, hi + pad)
}

/// One thing a legend names.
pub(crate) enum Key {
    Point(RGBColor),
    Band(RGBColor),
    Line(RGBColor),
}

/// A legend in a strip of its own above the plot, so it never covers a point.
pub(crate) fn legend(area: &Area<'_>, keys: &[(Key, &str)]) -> Result<()> {
    let mut x = 70;
    let y = 12;
    for (key, label) in keys {
        match key {
            Key::Point(c) => area.draw(&Circle::new((x + 6, y), 4, c.filled()))?,
            Key::Band(c) => {
                area.draw(&Rectangle::new([(x, y - 6), (x + 14, y + 6)], c.filled()))?
            }
            Key::Line(c) => area.draw(&PathElement::new(
                vec![(x, y), (x + 16, y)],
                c.stroke_width(2),
            ))?,
        }
        area.draw(&Text::new(
            label.to_string(),
            (x + 22, y - 7),
            ("sans-serif", 13).into_font(),
        ))?;
        x += 32 + 7 * label.chars().count() as i32;
    }
    Ok(())
}

/// `(x, residual, uncertainty)` of the rows where `keep` and x is finite, g.
fn points(xs: &[f64], c: &Comparison, keep: &dyn Fn(usize) -> bool) -> Vec<(f64, f64, f64)> {
    xs.iter()
        .zip(&c.rows)
        .enumerate()
        .filter(|(i, (x, _))| x.is_finite() && keep(*i))
        .map(|(_, (x, r))| (*x, r.residual_g, r.uncertainty_g))
        .collect()
}

/// A row of residual panels: what [`panel_pair`] draws.
struct Pair<'a> {
    /// File name stem (`-before.svg`, `-after.svg` appended).
    file: String,
    before_title: String,
    /// `None`: no after panel (the lab added no effect: it would repeat the before).
    after_title: Option<String>,
    x_var: &'a str,
    floor_g: f64,
    span: (f64, f64),
}

/// Draws the before panel (and the after one) of a row into `plots`; returns their
/// indices there.
fn panel_pair(
    plots: &mut Vec<(String, String)>,
    row: &Pair<'_>,
    before: &[(f64, f64, f64)],
    after: &[(f64, f64, f64)],
) -> Result<Vec<usize>> {
    let mut at = Vec::with_capacity(2);
    let sides = [
        (Some(&row.before_title), "before", before, BEFORE),
        (row.after_title.as_ref(), "after", after, AFTER),
    ];
    for (title, side, pts, colour) in sides {
        let Some(title) = title else { continue };
        plots.push((
            format!("{}-{side}.svg", row.file),
            residual_panel(title, row.x_var, pts, colour, row.floor_g, row.span)?,
        ));
        at.push(plots.len() - 1);
    }
    Ok(at)
}

/// One panel: the residual (g) against a variable, with its uncertainty bars, the
/// band of plus or minus the noise floor, and the zero line; on its own scale.
fn residual_panel(
    title: &str,
    x_var: &str,
    pts: &[(f64, f64, f64)],
    colour: RGBColor,
    noise_floor_g: f64,
    x_span: (f64, f64),
) -> Result<String> {
    let (x_title, x_unit) = describe(x_var);
    let (x0, x1) = padded(x_span.0, x_span.1);
    let floor = if noise_floor_g.is_finite() {
        noise_floor_g
    } else {
        0.0
    };
    let (lo, hi) =
        finite_range(pts.iter().flat_map(|p| [p.1 - p.2, p.1 + p.2])).unwrap_or((-floor, floor));
    let (y0, y1) = padded(lo.min(-floor).min(0.0), hi.max(floor).max(0.0));
    let fx = axis_formatter(x0, x1, x_unit);
    let fy = axis_formatter(y0, y1, "g");
    svg(PANEL.0, PANEL.1, |area| {
        let (top, plot) = area.split_vertically(48);
        top.draw(&Text::new(
            title.to_string(),
            (70, 4),
            ("sans-serif", 15).into_font(),
        ))?;
        let strip = top.split_vertically(22).1;
        legend(
            &strip,
            &[
                (Key::Point(colour), "residual, with its uncertainty bar"),
                (Key::Band(FLOOR_BAND), "± noise floor"),
            ],
        )?;
        let mut chart = ChartBuilder::on(&plot)
            .margin_right(16)
            .margin_top(4)
            .x_label_area_size(40)
            .y_label_area_size(76)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart.draw_series(std::iter::once(Rectangle::new(
            [(x0, -floor), (x1, floor)],
            FLOOR_BAND.filled(),
        )))?;
        chart
            .configure_mesh()
            .light_line_style(TRANSPARENT)
            .bold_line_style(RGBColor(215, 215, 215))
            .x_desc(x_title)
            .y_desc("residual, g")
            .x_labels(7)
            .y_labels(6)
            .x_label_formatter(&fx)
            .y_label_formatter(&fy)
            .draw()?;
        chart.draw_series(LineSeries::new(
            [(x0, 0.0), (x1, 0.0)],
            GREY.stroke_width(1),
        ))?;
        chart.draw_series(pts.iter().map(|&(x, y, u)| {
            ErrorBar::new_vertical(x, y - u, y, y + u, colour.stroke_width(1), 6)
        }))?;
        chart.draw_series(
            pts.iter()
                .map(|&(x, y, _)| Circle::new((x, y), 3, colour.filled())),
        )?;
        Ok(())
    })
}

/// The effects added, for a caption: `+ mount_resonance`.
fn added_label(effects_added: &[String]) -> String {
    if effects_added.is_empty() {
        "no effect added".into()
    } else {
        format!("+ {}", effects_added.join(" + "))
    }
}

/// The residual RMS at each step of the stepwise search (log scale), against the
/// noise floor; the model as is in red, the last step in blue.
fn steps_plot(steps: &[Step], noise_floor_g: f64) -> Result<String> {
    let ys: Vec<f64> = steps.iter().map(|s| s.rms_residual_g.max(1e-15)).collect();
    let floor = if noise_floor_g.is_finite() && noise_floor_g > 0.0 {
        noise_floor_g
    } else {
        ys.iter().copied().fold(f64::INFINITY, f64::min)
    };
    // Whole decades, so that the log axis has labelled ticks even over a narrow span.
    let lo = 10f64.powf(
        (ys.iter().copied().fold(floor, f64::min) / 2.0)
            .log10()
            .floor(),
    );
    let hi = 10f64.powf(
        (ys.iter().copied().fold(floor, f64::max) * 2.0)
            .log10()
            .ceil(),
    );
    let n = steps.len().max(1);
    let x1 = n as f64 - 0.4;
    svg(1320, 340, |area| {
        let (top, plot) = area.split_vertically(48);
        top.draw(&Text::new(
            "residual RMS at each step of the stepwise search (each step refits all the chosen effects jointly)",
            (90, 4),
            ("sans-serif", 15).into_font(),
        ))?;
        legend(
            &top.split_vertically(22).1,
            &[
                (Key::Point(BEFORE), "model as given"),
                (Key::Point(AFTER), "after the last step"),
                (Key::Line(GREY), "noise floor (RMS of the uncertainties)"),
            ],
        )?;
        let mut chart = ChartBuilder::on(&plot)
            .margin_right(30)
            .margin_top(4)
            .x_label_area_size(40)
            .y_label_area_size(90)
            .build_cartesian_2d(-0.6..x1, (lo..hi).log_scale())?;
        let label = |x: &f64| {
            let i = x.round();
            if (x - i).abs() > 0.01 || i < 0.0 {
                return String::new();
            }
            steps
                .get(i as usize)
                .map_or(String::new(), |s| s.action.clone())
        };
        chart
            .configure_mesh()
            .light_line_style(TRANSPARENT)
            .bold_line_style(RGBColor(215, 215, 215))
            .disable_x_mesh()
            .x_labels(n + 1)
            .x_label_formatter(&label)
            .y_label_formatter(&|v| eng(*v, "g"))
            .x_desc("step")
            .y_desc("residual RMS, g")
            .draw()?;
        chart.draw_series(LineSeries::new(
            [(-0.6, floor), (x1, floor)],
            GREY.stroke_width(2),
        ))?;
        chart.draw_series(LineSeries::new(
            ys.iter().enumerate().map(|(i, y)| (i as f64, *y)),
            GREY.stroke_width(1),
        ))?;
        for (i, (s, y)) in steps.iter().zip(&ys).enumerate() {
            let colour = if i == 0 {
                BEFORE
            } else if i + 1 == steps.len() {
                AFTER
            } else {
                GREY
            };
            chart.draw_series(std::iter::once(Circle::new(
                (i as f64, *y),
                6,
                colour.filled(),
            )))?;
            chart.draw_series(std::iter::once(Text::new(
                format!(
                    "{}, chi2/dof {}",
                    eng(s.rms_residual_g, "g"),
                    num(s.chi2_per_dof)
                ),
                (i as f64 + 0.06, *y * 1.25),
                ("sans-serif", 13).into_font(),
            )))?;
        }
        Ok(())
    })
}

/// Candidates of the first round: `-delta BIC` per candidate, log scale.
fn ranking_plot(d: &Diagnosis) -> Result<String> {
    // (kind, bar length, label, supported): the bar is -delta BIC from 1 (none for a
    // candidate that does not lower the BIC), the label the delta BIC itself.
    let bars: Vec<(String, f64, String, bool)> = d
        .candidates
        .iter()
        .map(|c| {
            let (v, label) = c.fit.as_ref().map_or((1.0, "not applicable".into()), |f| {
                (
                    (-f.delta_bic).max(1.0),
                    format!("delta BIC {}", num(f.delta_bic)),
                )
            });
            (c.kind.clone(), v, label, c.supported)
        })
        .collect();
    let n = bars.len().max(1);
    let support = (-d.options.bic_support).max(1.0);
    let xmax = bars.iter().map(|b| b.1).fold(support, f64::max) * 30.0;
    svg(1320, 80 + 26 * n as u32, |area| {
        let (top, plot) = area.split_vertically(48);
        top.draw(&Text::new(
            "candidates, each alone against the model as given: the BIC it gains (-delta BIC)",
            (30, 4),
            ("sans-serif", 15).into_font(),
        ))?;
        let threshold = format!("supported (delta BIC < {})", num(d.options.bic_support));
        legend(
            &top.split_vertically(22).1,
            &[
                (Key::Band(SUPPORTED), threshold.as_str()),
                (Key::Band(NOT_SUPPORTED), "not supported"),
                (Key::Line(GREY), "support threshold"),
            ],
        )?;
        let mut chart = ChartBuilder::on(&plot)
            .margin_right(30)
            .margin_left(20)
            .x_label_area_size(36)
            .y_label_area_size(10)
            .build_cartesian_2d((1.0..xmax).log_scale(), 0.0..n as f64)?;
        chart
            .configure_mesh()
            .disable_y_mesh()
            .disable_y_axis()
            .light_line_style(TRANSPARENT)
            .x_label_formatter(&|v| num(*v))
            .x_desc("-delta BIC (log scale)")
            .draw()?;
        for (i, (kind, v, label, supported)) in bars.iter().enumerate() {
            let y = (n - 1 - i) as f64;
            let colour = if *supported { SUPPORTED } else { NOT_SUPPORTED };
            chart.draw_series(std::iter::once(Rectangle::new(
                [(1.0, y + 0.15), (*v, y + 0.85)],
                colour.filled(),
            )))?;
            chart.draw_series(std::iter::once(Text::new(
                format!("{kind}: {label}"),
                (*v * 1.15, y + 0.75),
                ("sans-serif", 13).into_font(),
            )))?;
        }
        chart.draw_series(LineSeries::new(
            [(support, 0.0), (support, n as f64)],
            GREY.stroke_width(2),
        ))?;
        Ok(())
    })
}

/// A plain number to 3 or 4 significant digits (BIC, chi2 per dof, p-values).
pub(crate) fn num(x: f64) -> String {
    if !x.is_finite() {
        return "n/a".into();
    }
    let a = x.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e6).contains(&a) {
        format!("{x:.2e}")
    } else if a >= 100.0 {
        format!("{x:.0}")
    } else if a >= 1.0 {
        format!("{x:.3}")
            .trim_end_matches('0')
            .trim_end_matches('.')
            .to_string()
    } else {
        format!("{x:.4}")
    }
}

/// A parameter's value and uncertainty, rounded to the uncertainty's second digit,
/// with the unit its name carries: `48.0012 ± 0.0021 Hz`.
/// `value_pm`, or with a profile-likelihood interval unlike `+- sigma`: the value
/// with its 68 % reach below and above (`40.22 −2.02 +2.76 Hz`), both reaches in the
/// value's prefix and to the decimals of the smaller.
fn param_pm(p: &crate::fit::FittedParam) -> String {
    let (m, h) = (p.sigma_minus, p.sigma_plus);
    if !(crate::fit::asymmetric(p) && m > 0.0 && h > 0.0) {
        return value_pm(&p.name, p.value, p.sigma);
    }
    let unit = describe(&p.name).1;
    let small = m.min(h);
    let e = if unit.is_empty() || unit == "deg" || unit == "s" {
        0
    } else {
        eng_exponent(p.value.abs().max(small), unit)
    };
    let scale = 10f64.powi(e);
    let decimals = (1.0 - (small / scale).log10().floor()).clamp(0.0, 12.0) as usize;
    if (p.value / scale).abs() >= 1e7 || decimals > 8 {
        return format!(
            "{:.3e} −{m:.2e} +{h:.2e} {unit} (profile likelihood)",
            p.value
        );
    }
    format!(
        "{:.decimals$} −{:.decimals$} +{:.decimals$} {}{unit} (profile likelihood)",
        p.value / scale,
        m / scale,
        h / scale,
        prefix(e)
    )
    .replace("  ", " ")
}

pub(crate) fn value_pm(name: &str, value: f64, sigma: f64) -> String {
    let unit = describe(name).1;
    if !sigma.is_finite() || sigma <= 0.0 {
        let v = if unit.is_empty() {
            num(value)
        } else {
            eng(value, unit)
        };
        return format!("{v} (not determined by these data)");
    }
    let e = if unit.is_empty() || unit == "deg" || unit == "s" {
        0
    } else {
        eng_exponent(value.abs().max(sigma), unit)
    };
    let scale = 10f64.powi(e);
    let decimals = (1.0 - (sigma / scale).log10().floor()).clamp(0.0, 12.0) as usize;
    if (value / scale).abs() >= 1e7 || decimals > 8 {
        return format!("{value:.3e} ± {sigma:.2e} {unit}")
            .trim_end()
            .to_string();
    }
    format!(
        "{:.decimals$} ± {:.decimals$} {}{unit}",
        value / scale,
        sigma / scale,
        prefix(e)
    )
    .trim_end()
    .to_string()
}

pub(crate) fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// The verdict in words, for the top of the page.
fn verdict_html(d: &Diagnosis, rms_after_g: f64) -> String {
    let s = &d.comparison.summary;
    let floor = eng(s.noise_floor_g, "g");
    let code = |k: &[String]| {
        k.iter()
            .map(|k| format!("<code>{}</code>", esc(k)))
            .collect::<Vec<_>>()
            .join(" + ")
    };
    match &d.verdict {
        Verdict::Noise {
            p_value,
            chi2_per_dof,
        } => format!(
            "<b>The model agrees with the measurements within their uncertainty</b> \
             (residual RMS {} against a noise floor of {floor}, chi2 per dof {}, p = {}): \
             no effect is missing that these data can see.",
            eng(s.rms_residual_g, "g"),
            num(*chi2_per_dof),
            num(*p_value)
        ),
        Verdict::Effect {
            kinds,
            delta_bic,
            rms_residual_before_g,
            chi2_per_dof_after,
            physics,
            ..
        } => {
            let mut h = format!(
                "<b>Missing effect{}: {}</b> (delta BIC {}). With {} the residual RMS falls \
                 from {} to {} (noise floor {floor}; chi2 per dof {}).",
                if kinds.len() > 1 { "s" } else { "" },
                code(kinds),
                num(*delta_bic),
                if kinds.len() > 1 { "them" } else { "it" },
                eng(*rms_residual_before_g, "g"),
                eng(rms_after_g, "g"),
                num(*chi2_per_dof_after)
            );
            for p in physics {
                let _ = write!(h, "<br>{}", esc(p));
            }
            h
        }
        Verdict::Confounded {
            kinds,
            correlation,
            suggestions,
            found,
        } => {
            let mut h = String::new();
            if !found.is_empty() {
                let _ = write!(h, "Found first: {}. ", code(found));
            }
            let _ = write!(
                h,
                "<b>Confounded: {} explain the residual equally well</b> (their VE changes \
                 correlate at {correlation:.4} over these data): they cannot be told apart here. \
                 Add conditions where they differ most:<ul>",
                kinds
                    .iter()
                    .map(|k| format!("<code>{}</code>", esc(k)))
                    .collect::<Vec<_>>()
                    .join(" and ")
            );
            for sg in suggestions {
                let preds: Vec<String> = sg
                    .predictions_g
                    .iter()
                    .map(|(k, v)| format!("{} {}", esc(k), eng(*v, "g")))
                    .collect();
                let _ = write!(
                    h,
                    "<li>{}: {} ({:.0} sigma apart)</li>",
                    esc(&sg.description),
                    preds.join(", "),
                    sg.separation_sigma
                );
            }
            h.push_str("</ul>");
            h
        }
        Verdict::Unexplained {
            chi2_per_dof,
            variables,
            best,
            best_explained_fraction,
            found,
            found_explained_fraction,
        } => {
            let mut h = if found.is_empty() {
                format!(
                    "<b>Unexplained structure</b> (chi2 per dof {}): no effect of the library \
                     explains it.",
                    num(*chi2_per_dof)
                )
            } else {
                format!(
                    "<b>Found {}</b> (removing {:.1} % of the chi-square), <b>but structure \
                     remains unexplained</b> (chi2 per dof {} with {}).",
                    code(found),
                    100.0 * found_explained_fraction,
                    num(*chi2_per_dof),
                    if found.len() > 1 { "them" } else { "it" }
                )
            };
            if !variables.is_empty() {
                let _ = write!(
                    h,
                    " The residual left follows {}.",
                    esc(&variables.join(", "))
                );
            }
            if let Some(b) = best {
                let _ = write!(
                    h,
                    " The best candidate left, <code>{}</code>, would explain only {:.1} % of it.",
                    esc(b),
                    100.0 * best_explained_fraction
                );
            }
            if let Some(e) = &d.empirical {
                let terms: Vec<String> = e
                    .terms
                    .iter()
                    .map(|t| format!("<code>{}</code> = {:.4e}", esc(&t.key), t.value))
                    .collect();
                let _ = write!(
                    h,
                    "<br><b>Beyond the library, NOT PHYSICAL:</b> an empirical correction in \
                     {} ({}), chosen by cross-validation, takes the residual to {} (chi2 per \
                     dof {}). Add it with <code>vibrocomp lab add empirical</code>.",
                    esc(&e.variables.join(", ")),
                    terms.join(", "),
                    eng(e.rms_residual_after_g, "g"),
                    num(e.chi2_per_dof_after)
                );
            } else if let Some(why) = &d.empirical_none {
                let _ = write!(h, "<br>Beyond the library: {}.", esc(why));
            }
            h
        }
    }
}

/// The stepwise search as a table.
fn steps_table(h: &mut String, steps: &[Step]) {
    h.push_str(
        "<table><tr><th>step</th><th>effects chosen</th><th>delta BIC</th>\
         <th>residual RMS</th><th>chi2 per dof</th><th>p-value</th>\
         <th>next best (delta BIC)</th></tr>",
    );
    for st in steps {
        let next: Vec<String> = st
            .runners_up
            .iter()
            .map(|(k, b)| format!("{} {}", esc(k), num(*b)))
            .collect();
        let _ = write!(
            h,
            "<tr><td class=l>{}</td><td class=l>{}</td><td>{}</td><td>{}</td><td>{}</td>\
             <td>{}</td><td class=l>{}</td></tr>",
            esc(&st.action),
            esc(&if st.effects.is_empty() {
                "none".into()
            } else {
                st.effects.join(" + ")
            }),
            num(st.delta_bic),
            eng(st.rms_residual_g, "g"),
            num(st.chi2_per_dof),
            num(st.p_value),
            next.join(", ")
        );
    }
    h.push_str("</table>");
}

/// The final joint fit: parameters, and their correlations.
fn fit_tables(h: &mut String, f: &EffectFit) {
    let _ = write!(
        h,
        "<p>{} fitted jointly to {} conditions ({} parameters): residual RMS {} → {}, \
         chi2 per dof {}, p = {}.</p>",
        esc(&f.kinds.join(" + ")),
        f.n,
        f.k,
        eng(f.rms_residual_before_g, "g"),
        eng(f.rms_residual_after_g, "g"),
        num(f.chi2_per_dof_after),
        num(f.p_value_after)
    );
    h.push_str(
        "<table><tr><th>effect</th><th>parameter</th><th>value ± standard uncertainty</th></tr>",
    );
    for p in &f.params {
        let _ = write!(
            h,
            "<tr><td class=l>{}</td><td class=l>{}</td><td>{}</td></tr>",
            esc(&p.effect),
            esc(&p.name),
            esc(&param_pm(p))
        );
    }
    h.push_str("</table>");
    if f.params.len() < 2 {
        return;
    }
    h.push_str("<h3>Correlations between the parameters</h3><table><tr><th></th>");
    for p in &f.params {
        let _ = write!(h, "<th>{}.{}</th>", esc(&p.effect), esc(&p.name));
    }
    h.push_str("</tr>");
    for (i, p) in f.params.iter().enumerate() {
        let _ = write!(
            h,
            "<tr><th class=l>{}.{}</th>",
            esc(&p.effect),
            esc(&p.name)
        );
        for j in 0..f.params.len() {
            let r = f
                .correlation
                .get(i)
                .and_then(|row| row.get(j))
                .copied()
                .unwrap_or(f64::NAN);
            // Shade by |r|: strong correlations (a parameter pair the data barely
            // separate) stand out.
            let shade = if r.is_finite() {
                (255.0 - 120.0 * r.abs()).round() as u8
            } else {
                255
            };
            let text = if r.is_finite() {
                format!("{r:+.3}")
            } else {
                "n/a".into()
            };
            let _ = write!(
                h,
                "<td style=\"background:rgb(255,{shade},{shade})\">{text}</td>"
            );
        }
        h.push_str("</tr>");
    }
    h.push_str("</table>");
}

/// What the report holds, for `--json`.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ReportSummary {
    pub plots: usize,
    pub ladder: Vec<LadderStep>,
    pub rms_before_g: f64,
    pub rms_after_g: f64,
    pub effects_added: Vec<String>,
    /// The noise floor (RMS of the uncertainties), g.
    pub noise_floor_g: f64,
    /// The variables plotted against, in order.
    pub variables: Vec<String>,
    /// The units plotted against time (MCAP logs; empty for campaign tables).
    pub time_units: Vec<String>,
}

/// What the report shows.
pub struct ReportInput<'a> {
    pub table: &'a CampaignTable,
    /// The model as given.
    pub model: &'a LabModel,
    /// Its diagnosis (the report quotes it in full, as `crate::text` writes it).
    pub diagnosis: &'a Diagnosis,
    /// The steps of the lab adding effects, and the model they end with.
    pub ladder: &'a [LadderStep],
    pub final_model: &'a LabModel,
    /// The comparison of the final model.
    pub after: &'a Comparison,
}

/// The units of an MCAP log's windows: `(unit number, name)`, from the `unit`
/// variable and the run ids (`NAME@12.50s`).
fn log_units(table: &CampaignTable) -> Vec<(f64, String)> {
    let Some(units) = table.variable_column("unit") else {
        return Vec::new();
    };
    let has_time = table
        .variable_column("t_s")
        .is_some_and(|t| t.iter().any(|x| x.is_finite()));
    if !has_time {
        return Vec::new();
    }
    let mut out: Vec<(f64, String)> = Vec::new();
    for (u, c) in units.iter().zip(&table.conditions) {
        if u.is_finite() && !out.iter().any(|(v, _)| v == u) {
            let name = c
                .run_id
                .split_once('@')
                .map_or(format!("unit {u}"), |(n, _)| n.to_string());
            out.push((*u, name));
        }
    }
    out.sort_by(|a, b| a.0.total_cmp(&b.0));
    out
}

/// The file whose presence marks a previous report in a folder (README, "Files").
pub const REPORT_FILES: &[&str] = &["index.html"];

/// A rendered report: the page and its plots, to be written into one folder.
#[derive(Debug, Clone)]
pub struct Report {
    /// `index.html`, every plot inline.
    pub index_html: String,
    /// Each plot as a file of its own beside it: `(file name, SVG)`.
    pub plots: Vec<(String, String)>,
    pub summary: ReportSummary,
}

/// Draws the report of `r` (module doc).
pub fn render(r: &ReportInput<'_>) -> Result<Report> {
    let ReportInput {
        table,
        model,
        diagnosis,
        ladder,
        final_model,
        after,
    } = *r;
    let before = &diagnosis.comparison;
    let s = &before.summary;
    let floor_g = s.noise_floor_g;
    let effects_added: Vec<String> = final_model
        .effect_kinds()
        .get(model.effects.len()..)
        .unwrap_or_default()
        .to_vec();
    let after_caption = format!("after: {}", added_label(&effects_added));
    let units = log_units(table);
    // The variables: the trends' order (strongest first), then the tone frequency and
    // aL3 if not already there, at most 6. The log's time and unit have a plot of
    // their own.
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
        v != "unit"
            && (units.is_empty() || (v != "t_s" && v != "vibrating_s"))
            && columns
                .iter()
                .any(|(n, xs)| n == v && xs.iter().any(|x| x.is_finite()))
    });
    variables.truncate(6);

    // (file name, svg, section)
    let mut plots: Vec<(String, String)> = Vec::new();
    // Each row of panels: before, and after when the lab added an effect (else it
    // would repeat the before).
    let with_after = !effects_added.is_empty();
    let mut residual_rows: Vec<Vec<usize>> = Vec::new();
    let all = |_: usize| true;
    for v in &variables {
        let xs = table
            .variable_column(v)
            .ok_or_else(|| Error::Invalid(format!("no variable {v}")))?;
        let span = finite_range(xs.iter().copied()).unwrap_or((0.0, 1.0));
        let (b, a) = (points(&xs, before, &all), points(&xs, after, &all));
        let name = describe(v).0;
        let panels = panel_pair(
            &mut plots,
            &Pair {
                file: format!("residual-{v}"),
                before_title: format!("before (model as given): residual against {name}"),
                after_title: with_after
                    .then(|| format!("{after_caption}: residual against {name}")),
                x_var: v,
                floor_g,
                span,
            },
            &b,
            &a,
        )?;
        residual_rows.push(panels);
    }
    let mut time_rows: Vec<Vec<usize>> = Vec::new();
    if !units.is_empty() {
        let ts = table.variable_column("t_s").unwrap_or_default();
        let us = table.variable_column("unit").unwrap_or_default();
        let span = finite_range(ts.iter().copied()).unwrap_or((0.0, 1.0));
        for (u, name) in &units {
            let keep = |i: usize| us.get(i) == Some(u);
            let (b, a) = (points(&ts, before, &keep), points(&ts, after, &keep));
            let panels = panel_pair(
                &mut plots,
                &Pair {
                    file: format!("time-unit{u}"),
                    before_title: format!("{name}, before (model as given): residual against time"),
                    after_title: with_after
                        .then(|| format!("{name}, {after_caption}: residual against time")),
                    x_var: "t_s",
                    floor_g,
                    span,
                },
                &b,
                &a,
            )?;
            time_rows.push(panels);
        }
    }
    let steps_at = if diagnosis.steps.is_empty() {
        None
    } else {
        plots.push(("steps.svg".into(), steps_plot(&diagnosis.steps, floor_g)?));
        Some(plots.len() - 1)
    };
    let ranking_at = if diagnosis.candidates.is_empty() {
        None
    } else {
        plots.push(("ranking.svg".into(), ranking_plot(diagnosis)?));
        Some(plots.len() - 1)
    };

    let mut h = String::new();
    let _ = write!(
        h,
        "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>vibrocomp lab report: {}</title>\
         <style>body{{font-family:sans-serif;margin:24px;max-width:1340px}}\
         table{{border-collapse:collapse;margin:6px 0}}td,th{{border:1px solid #bbb;padding:3px 8px;text-align:right}}\
         .l{{text-align:left}}.verdict{{background:#f3f6fb;border-left:6px solid #1f77b4;padding:10px 14px;font-size:17px}}\
         .row{{display:flex;gap:8px;margin-bottom:6px}}pre{{background:#f6f6f6;padding:8px;overflow-x:auto}}\
         h2{{margin-top:28px}}</style></head><body><h1>vibrocomp lab report</h1>",
        esc(&before.table)
    );
    let _ = write!(
        h,
        "<div class=verdict>{}</div>",
        verdict_html(diagnosis, after.summary.rms_residual_g)
    );
    let _ = write!(
        h,
        "<p>Data <b>{}</b>: {} conditions. Model as given: {} mode, effects: {}. \
         Effects added by the lab: {}. Evaluation path: {}.</p>",
        esc(&before.table),
        s.n,
        esc(&before.mode),
        esc(&if before.effects.is_empty() {
            "none".into()
        } else {
            before.effects.join(", ")
        }),
        esc(&if effects_added.is_empty() {
            "none".into()
        } else {
            effects_added.join(", ")
        }),
        // The report's fits are the statistics path's (docs/lab.md, "Which evaluation").
        if before.paths.waveform == 0 && after.paths.waveform == 0 {
            "statistics (each condition's VE from its stated vibration; `lab compare` \
             evaluates a log's windows on the waveform)"
                .to_string()
        } else {
            format!(
                "waveform for {} conditions, statistics for {}",
                after.paths.waveform, after.paths.statistics
            )
        },
    );
    let _ = write!(
        h,
        "<table><tr><th></th><th>residual RMS</th><th>max |residual|</th><th>chi2 per dof</th><th>p-value</th></tr>\
         <tr><th class=l>before (model as given)</th><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>\
         <tr><th class=l>after ({})</th><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>\
         <tr><th class=l>noise floor (RMS of the uncertainties)</th><td>{}</td><td></td><td>1 expected</td><td></td></tr></table>",
        eng(s.rms_residual_g, "g"),
        eng(s.max_abs_residual_g, "g"),
        num(s.chi2_per_dof),
        num(s.p_value),
        esc(&added_label(&effects_added)),
        eng(after.summary.rms_residual_g, "g"),
        eng(after.summary.max_abs_residual_g, "g"),
        num(after.summary.chi2_per_dof),
        num(after.summary.p_value),
        eng(floor_g, "g"),
    );
    let row = |h: &mut String, pair: &[usize]| {
        h.push_str("<div class=row>");
        for &i in pair {
            h.push_str(&plots[i].1);
        }
        h.push_str("</div>");
    };
    if !residual_rows.is_empty() {
        h.push_str(if with_after {
            "<h2>Residual against each variable</h2><p>Measured minus predicted VE, left \
             before (the model as given, red), right after (with the effects the lab found, \
             blue); each panel on its own scale. Bars: standard uncertainty; green band: \
             ± the noise floor.</p>"
        } else {
            "<h2>Residual against each variable</h2><p>Measured minus predicted VE of the \
             model as given (the lab added no effect). Bars: standard uncertainty; green \
             band: ± the noise floor.</p>"
        });
        for pair in &residual_rows {
            row(&mut h, pair);
        }
    }
    if !time_rows.is_empty() {
        h.push_str(
            "<h2>Residual against time, per unit</h2><p>Each window at its centre, in \
             seconds since the log's first sample.</p>",
        );
        for pair in &time_rows {
            row(&mut h, pair);
        }
    }
    if let Some(i) = steps_at {
        let _ = write!(
            h,
            "<h2>The stepwise search</h2><p>From the model as given, the lab adds the \
             candidate that lowers the BIC most while the drop is beyond {} (and removes \
             one whose removal lowers it), refitting every chosen effect jointly.</p>{}",
            num(-diagnosis.options.bic_support),
            plots[i].1
        );
        steps_table(&mut h, &diagnosis.steps);
    }
    if let Some(f) = &diagnosis.selected {
        h.push_str("<h2>The final joint fit</h2>");
        fit_tables(&mut h, f);
    }
    if let Some(i) = ranking_at {
        let _ = write!(
            h,
            "<h2>First round: every candidate alone</h2>{}",
            plots[i].1
        );
    }
    let _ = write!(
        h,
        "<h2>The diagnosis in full</h2><pre>{}</pre>",
        esc(&{
            let mut text = String::new();
            crate::text::write_diagnosis(&mut text, diagnosis);
            text
        })
    );
    h.push_str("</body></html>\n");
    let summary = ReportSummary {
        plots: plots.len(),
        ladder: ladder.to_vec(),
        rms_before_g: s.rms_residual_g,
        rms_after_g: after.summary.rms_residual_g,
        effects_added,
        noise_floor_g: floor_g,
        variables,
        time_units: units.into_iter().map(|(_, n)| n).collect(),
    };
    Ok(Report {
        index_html: h,
        plots,
        summary,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_are_in_engineering_form() {
        assert_eq!(eng(1.2e-3, "g"), "1.20 mg");
        assert_eq!(eng(35e-9, "g"), "35.0 ng");
        assert_eq!(eng(48.0, "Hz"), "48.0 Hz");
        assert_eq!(eng(-250e-6, "g"), "-250 µg");
        assert_eq!(eng(1500.0, "Hz"), "1.50 kHz");
        assert_eq!(eng(1500.0, "s"), "1500 s");
        assert_eq!(eng(0.0, "g"), "0 g");
        assert_eq!(eng(1e-7, "g"), "100 ng");
        assert_eq!(eng(999.7e-9, "g"), "1.00 µg");
        let f = axis_formatter(-1.2e-3, 1.2e-3, "g");
        assert_eq!(f(&5e-4), "0.5 mg");
        assert_eq!(f(&0.0), "0");
        assert_eq!(value_pm("freq_hz", 48.00123, 0.0021), "48.0012 ± 0.0021 Hz");
        assert_eq!(value_pm("q", 1.5601, 0.00042), "1.56010 ± 0.00042");
        let p = crate::fit::FittedParam {
            effect: "mount_resonance".into(),
            name: "freq_hz".into(),
            value: 40.21772,
            sigma: 2.25,
            sigma_minus: 2.0224,
            sigma_plus: 2.7593,
            three_sigma_minus: 5.7,
            three_sigma_plus: 65.6,
        };
        assert_eq!(param_pm(&p), "40.2 −2.0 +2.8 Hz (profile likelihood)");
        let q = crate::fit::FittedParam {
            sigma_minus: 2.2,
            sigma_plus: 2.3,
            ..p.clone()
        };
        assert_eq!(param_pm(&q), "40.2 ± 2.2 Hz");
    }
}
