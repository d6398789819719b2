//! The lab's report of a diagnosis on the waveform ([`crate::wave_diagnose`], issue
//! 44): the same self-contained HTML page with inline SVG plots as the statistics
//! path's ([`crate::report`], whose look, colours and number formats it shares), for
//! logs whose every accelerometer reading was predicted from the vibration sensors'
//! samples:
//!
//! - the verdict in words, the effects found, each parameter's value ± its sandwich
//!   uncertainty (the sensors' delay in µs when fitted), the chi2 per reading and the
//!   lack of fit's z before and after, the noise per unit and where it came from, the
//!   runs;
//! - **the residual of every reading along each run**, before (the model as is, red)
//!   and after (the final model, blue), one figure per run and side with a strip per
//!   unit on its own scale, the vibrating readings in colour and the quiet ones in
//!   grey, the band of ± 1 sigma of the unit's noise in green;
//! - the 1 s windows' mean residual along each run, vibrating (filled) and quiet
//!   (hollow), against ± the quiet windows' RMS;
//! - each round's candidates: delta BIC on a symmetric log scale, and a table with
//!   their parameters and the candidates that could not be fitted;
//! - the diagnosis as `vibrocomp lab diagnose` prints it ([`crate::wave_text`]).
//!
//! **Size.** A run of more than [`MAX_POINTS`] readings is drawn in blocks of
//! `ceil(readings / MAX_BLOCKS)` consecutive readings: per block, unit and kind
//! (vibrating, quiet), the band from the smallest to the largest residual, the
//! blocks of a stretch joined into one SVG polygon. Every reading thus still shows
//! (an outlier widens its block's band) while a figure holds about `3 x 4 x
//! MAX_BLOCKS` polygon vertices (or `3 x MAX_POINTS` points, some 100 kB), whatever
//! the log's length: 8 runs of 19 200 readings make a report of about 2 MB, every
//! plot counted twice (inline and as its file), and no number of readings a run
//! makes it pass 5 MB for 8 runs (a unit test holds both). A band spans the
//! extremes of its block: for noise alone, about ± 2.5 sigma at 100 readings a block,
//! so the vibrating readings compare with the quiet ones beside them, and the ± 1
//! sigma band gives the scale.

use crate::report::{
    axis_formatter, eng, esc, finite_range, legend, num, padded, svg, value_pm, Area, Key, Report,
    ReportSummary, AFTER, BEFORE, FLOOR_BAND, GREY, NOT_SUPPORTED, PANEL, SUPPORTED,
};
use crate::wave_diagnose::{
    CandidateOut, ParamOut, RunResidual, StepOut, WaveDiagnosis, WindowOut,
};
use crate::wave_text::{self, delay_in_us, effect_groups, fitted_delay, DELAY_KIND};
use crate::{LabModel, Result};
use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint};
use plotters::prelude::*;
use std::fmt::Write as _;

/// A run with at most this many readings has each drawn as a point.
pub const MAX_POINTS: usize = 400;
/// A longer run is drawn in this many blocks at most (about two per pixel column of
/// a panel's plot).
pub const MAX_BLOCKS: usize = 300;

const UG_PER_G: f64 = 1e6;
/// The quiet readings (the noise's own reference).
const QUIET: RGBColor = RGBColor(150, 150, 150);
/// The lines at ± 1 sigma of the noise, over the band.
const NOISE_LINE: RGBColor = RGBColor(44, 140, 44);
/// The three units in the windows' plot: neither red, blue nor green, which mean
/// before, after and noise.
const UNIT_COLOURS: [RGBColor; 3] = [
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(140, 86, 75),
];

/// A run's residual figure: a title strip and three unit strips.
const RUN_FIGURE: (u32, u32) = (PANEL.0, 560);

/// Consecutive readings of one unit and one kind (vibrating or quiet): their time
/// span, s, and their residual's extremes, ug.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Block {
    /// Its index along the run (blocks of consecutive indices join into a stretch).
    chunk: usize,
    t0_s: f64,
    t1_s: f64,
    lo_ug: f64,
    hi_ug: f64,
}

/// What a unit's strip draws of a run.
#[derive(Debug, Clone)]
struct Trace {
    /// Readings per block (1: every reading a point).
    per: usize,
    /// Half the readings' period, s: a block's band reaches this beyond its readings.
    half_period_s: f64,
    vibrating: Vec<Block>,
    quiet: Vec<Block>,
}

/// The blocks of unit `unit` along run `r` (module doc, "Size"); readings whose time
/// or residual is not finite (not used) are left out.
fn trace(r: &RunResidual, unit: usize) -> Trace {
    let n = r.t_s.len().min(r.quiet.len()).min(r.residual_g.len());
    let per = if n <= MAX_POINTS {
        1
    } else {
        n.div_ceil(MAX_BLOCKS)
    };
    let half_period_s = match finite_range(r.t_s.iter().copied()) {
        Some((a, b)) if n > 1 => 0.5 * (b - a) / (n - 1) as f64,
        _ => 0.0,
    };
    let mut out = Trace {
        per,
        half_period_s,
        vibrating: Vec::new(),
        quiet: Vec::new(),
    };
    for (chunk, start) in (0..n).step_by(per).enumerate() {
        let mut acc: [Option<Block>; 2] = [None, None];
        for k in start..(start + per).min(n) {
            let (t, y) = (r.t_s[k], r.residual_g[k][unit] * UG_PER_G);
            if !(t.is_finite() && y.is_finite()) {
                continue;
            }
            let b = acc[usize::from(r.quiet[k])].get_or_insert(Block {
                chunk,
                t0_s: t,
                t1_s: t,
                lo_ug: y,
                hi_ug: y,
            });
            b.t0_s = b.t0_s.min(t);
            b.t1_s = b.t1_s.max(t);
            b.lo_ug = b.lo_ug.min(y);
            b.hi_ug = b.hi_ug.max(y);
        }
        let [vibrating, quiet] = acc;
        out.vibrating.extend(vibrating);
        out.quiet.extend(quiet);
    }
    out
}

/// A stretch of blocks as a polygon: along their maxima, back along their minima.
fn envelope(stretch: &[Block], half_period_s: f64) -> Vec<(f64, f64)> {
    let h = half_period_s;
    let mut pts: Vec<(f64, f64)> = stretch
        .iter()
        .flat_map(|b| [(b.t0_s - h, b.hi_ug), (b.t1_s + h, b.hi_ug)])
        .collect();
    pts.extend(
        stretch
            .iter()
            .rev()
            .flat_map(|b| [(b.t1_s + h, b.lo_ug), (b.t0_s - h, b.lo_ug)]),
    );
    pts
}

/// A strip: one unit's residual along the run, with ± 1 sigma of its noise.
fn unit_strip(
    area: &Area<'_>,
    unit: usize,
    tr: &Trace,
    sigma_g: f64,
    colour: RGBColor,
    span_s: (f64, f64),
    last: bool,
) -> Result<()> {
    let sigma_ug = if sigma_g.is_finite() {
        sigma_g * UG_PER_G
    } else {
        0.0
    };
    let all = tr.vibrating.iter().chain(&tr.quiet);
    let (lo, hi) =
        finite_range(all.flat_map(|b| [b.lo_ug, b.hi_ug])).unwrap_or((-sigma_ug, sigma_ug));
    let (y0, y1) = padded(lo.min(-sigma_ug), hi.max(sigma_ug));
    let (x0, x1) = padded(span_s.0, span_s.1);
    let fx = axis_formatter(x0, x1, "s");
    let fy = axis_formatter(y0, y1, "");
    let mut chart = ChartBuilder::on(area)
        .margin_right(16)
        .margin_top(6)
        .x_label_area_size(if last { 40 } else { 22 })
        .y_label_area_size(76)
        .build_cartesian_2d(x0..x1, y0..y1)?;
    chart.draw_series(std::iter::once(Rectangle::new(
        [(x0, -sigma_ug), (x1, sigma_ug)],
        FLOOR_BAND.filled(),
    )))?;
    let mut mesh = chart.configure_mesh();
    mesh.light_line_style(TRANSPARENT)
        .bold_line_style(RGBColor(215, 215, 215))
        .y_desc(format!("unit {unit}, µg"))
        .x_labels(7)
        .y_labels(5)
        .x_label_formatter(&fx)
        .y_label_formatter(&fy);
    if last {
        mesh.x_desc("time since the run's first reading, s");
    }
    mesh.draw()?;
    chart.draw_series(LineSeries::new(
        [(x0, 0.0), (x1, 0.0)],
        GREY.stroke_width(1),
    ))?;
    for (blocks, c) in [(&tr.quiet, QUIET), (&tr.vibrating, colour)] {
        if tr.per == 1 {
            chart.draw_series(
                blocks
                    .iter()
                    .map(|b| Circle::new((b.t0_s, b.lo_ug), 2, c.filled())),
            )?;
        } else {
            chart.draw_series(
                blocks
                    .chunk_by(|a, b| b.chunk == a.chunk + 1)
                    .map(|st| Polygon::new(envelope(st, tr.half_period_s), c.mix(0.75).filled())),
            )?;
        }
    }
    for y in [-sigma_ug, sigma_ug] {
        chart.draw_series(LineSeries::new(
            [(x0, y), (x1, y)],
            NOISE_LINE.stroke_width(1),
        ))?;
    }
    Ok(())
}

/// A run's residual figure: a strip per unit.
fn run_figure(
    title: &str,
    r: &RunResidual,
    sigma_g: &[f64; 3],
    colour: RGBColor,
) -> Result<String> {
    let traces: Vec<Trace> = (0..3).map(|u| trace(r, u)).collect();
    let span_s = finite_range(r.t_s.iter().copied()).unwrap_or((0.0, 1.0));
    let per = traces.first().map_or(1, |t| t.per);
    let title = if per > 1 {
        format!("{title} (bands: min to max of {per} readings)")
    } else {
        title.to_string()
    };
    svg(RUN_FIGURE.0, RUN_FIGURE.1, |area| {
        let (top, body) = area.split_vertically(48);
        top.draw(&Text::new(title, (70, 4), ("sans-serif", 15).into_font()))?;
        legend(
            &top.split_vertically(22).1,
            &[
                (Key::Band(colour), "vibrating readings"),
                (Key::Band(QUIET), "quiet readings"),
                (Key::Line(NOISE_LINE), "± 1 sigma noise"),
            ],
        )?;
        let strips = body.split_evenly((3, 1));
        for (u, strip) in strips.iter().enumerate() {
            let sigma = sigma_g.get(u).copied().unwrap_or(f64::NAN);
            unit_strip(strip, u, &traces[u], sigma, colour, span_s, u == 2)?;
        }
        Ok(())
    })
}

/// A run's 1 s windows: each unit's mean residual, vibrating filled and quiet hollow,
/// against ± the quiet windows' RMS.
fn windows_figure(log: &str, ws: &[&WindowOut], noise_g: f64, window_s: f64) -> Result<String> {
    let noise_ug = if noise_g.is_finite() {
        noise_g * UG_PER_G
    } else {
        0.0
    };
    let span_s = finite_range(ws.iter().map(|w| w.t_s)).unwrap_or((0.0, 1.0));
    let (x0, x1) = padded(span_s.0, span_s.1);
    let ys = ws.iter().flat_map(|w| w.residual_g.map(|r| r * UG_PER_G));
    let (lo, hi) = finite_range(ys).unwrap_or((-noise_ug, noise_ug));
    let (y0, y1) = padded(lo.min(-noise_ug).min(0.0), hi.max(noise_ug).max(0.0));
    let fx = axis_formatter(x0, x1, "s");
    let fy = axis_formatter(y0, y1, "");
    let title = format!("{log}: {window_s} s windows' mean residual (hollow: quiet windows)");
    svg(PANEL.0, PANEL.1, |area| {
        let (top, plot) = area.split_vertically(48);
        top.draw(&Text::new(title, (70, 4), ("sans-serif", 15).into_font()))?;
        legend(
            &top.split_vertically(22).1,
            &[
                (Key::Point(UNIT_COLOURS[0]), "unit 0"),
                (Key::Point(UNIT_COLOURS[1]), "unit 1"),
                (Key::Point(UNIT_COLOURS[2]), "unit 2"),
                (Key::Band(FLOOR_BAND), "± noise RMS of the quiet windows"),
            ],
        )?;
        let mut chart = ChartBuilder::on(&plot)
            .margin_right(16)
            .margin_top(4)
            .x_label_area_size(40)
            .y_label_area_size(76)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart.draw_series(std::iter::once(Rectangle::new(
            [(x0, -noise_ug), (x1, noise_ug)],
            FLOOR_BAND.filled(),
        )))?;
        chart
            .configure_mesh()
            .light_line_style(TRANSPARENT)
            .bold_line_style(RGBColor(215, 215, 215))
            .x_desc("window centre since the run's first reading, s")
            .y_desc("mean residual, µg")
            .x_labels(7)
            .y_labels(6)
            .x_label_formatter(&fx)
            .y_label_formatter(&fy)
            .draw()?;
        chart.draw_series(LineSeries::new(
            [(x0, 0.0), (x1, 0.0)],
            GREY.stroke_width(1),
        ))?;
        for (u, c) in UNIT_COLOURS.iter().enumerate() {
            chart.draw_series(
                ws.iter()
                    .filter(|w| w.residual_g[u].is_finite() && w.t_s.is_finite())
                    .map(|w| {
                        let style = if w.quiet {
                            c.stroke_width(1)
                        } else {
                            c.filled()
                        };
                        Circle::new((w.t_s, w.residual_g[u] * UG_PER_G), 3, style)
                    }),
            )?;
        }
        Ok(())
    })
}

/// The symmetric log of a delta BIC: `sign(x) log10(1 + |x|)`, linear through 0.
fn symlog(x: f64) -> f64 {
    x.signum() * x.abs().ln_1p() / std::f64::consts::LN_10
}

/// [`symlog`]'s inverse.
fn symlog_inv(y: f64) -> f64 {
    y.signum() * (10f64.powf(y.abs()) - 1.0)
}

/// A linear axis over `range` with its ticks at `ticks` (plotters' `WithKeyPoints`
/// has no default formatting, which its mesh needs even with a formatter given).
struct Ticked {
    range: (f64, f64),
    ticks: Vec<f64>,
}

impl Ranged for Ticked {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        let (a, b) = self.range;
        let f = (value - a) / (b - a);
        limit.0 + (f * f64::from(limit.1 - limit.0)).round() as i32
    }

    fn key_points<H: KeyPointHint>(&self, _hint: H) -> Vec<f64> {
        self.ticks.clone()
    }

    fn range(&self) -> std::ops::Range<f64> {
        self.range.0..self.range.1
    }
}

/// A candidate's name in a round: `sensor_error, unit 2`.
fn candidate_label(c: &CandidateOut) -> String {
    match c.unit {
        Some(u) => format!("{}, unit {u}", c.kind),
        None => c.kind.clone(),
    }
}

/// A round's candidates that were fitted, best first: delta BIC as bars on a
/// symmetric log scale, the support threshold and zero as lines. `None` when no
/// candidate of the round was fitted.
fn round_figure(title: &str, step: &StepOut, support: f64) -> Result<Option<String>> {
    let mut bars: Vec<&CandidateOut> = step
        .candidates
        .iter()
        .filter(|c| c.error.is_none() && c.delta_bic.is_finite())
        .collect();
    if bars.is_empty() {
        return Ok(None);
    }
    bars.sort_by(|a, b| a.delta_bic.total_cmp(&b.delta_bic));
    let n = bars.len();
    let (lo, hi) = finite_range(bars.iter().map(|c| symlog(c.delta_bic)))
        .map_or((-1.0, 1.0), |(a, b)| {
            (a.min(symlog(support)).min(0.0), b.max(0.0))
        });
    let width = (hi - lo).max(1.0);
    // Room on the right for the values written beside the bars.
    let (x0, x1) = (lo - 0.04 * width, hi + 0.22 * width);
    let mut ticks = vec![0.0];
    for k in 0..=12 {
        let d = 10f64.powi(k);
        for x in [symlog(-d), symlog(d)] {
            if (x0..=x1).contains(&x) {
                ticks.push(x);
            }
        }
    }
    ticks.sort_by(f64::total_cmp);
    let labels: Vec<String> = bars.iter().map(|c| candidate_label(c)).collect();
    let centres: Vec<f64> = (0..n).map(|i| i as f64 + 0.5).collect();
    let fx = |x: &f64| num(symlog_inv(*x).round());
    let fy = |y: &f64| {
        let row = n as f64 - 1.0 - y.floor();
        if row < 0.0 {
            return String::new();
        }
        labels.get(row as usize).cloned().unwrap_or_default()
    };
    let threshold = format!("supported (delta BIC ≤ {})", num(support));
    // 60 px for the plot at least, so that one bar keeps the axis' fonts.
    let out = svg(1320, 150 + 26 * n as u32, |area| {
        let (top, plot) = area.split_vertically(48);
        top.draw(&Text::new(
            title.to_string(),
            (30, 4),
            ("sans-serif", 15).into_font(),
        ))?;
        legend(
            &top.split_vertically(22).1,
            &[
                (Key::Band(SUPPORTED), threshold.as_str()),
                (Key::Band(NOT_SUPPORTED), "not supported"),
                (Key::Line(GREY), "support threshold and 0"),
            ],
        )?;
        let mut chart = ChartBuilder::on(&plot)
            .margin_right(30)
            .margin_left(10)
            .x_label_area_size(40)
            .y_label_area_size(240)
            .build_cartesian_2d(
                Ticked {
                    range: (x0, x1),
                    ticks,
                },
                Ticked {
                    range: (0.0, n as f64),
                    ticks: centres,
                },
            )?;
        chart
            .configure_mesh()
            .disable_y_mesh()
            .light_line_style(TRANSPARENT)
            .bold_line_style(RGBColor(225, 225, 225))
            .x_label_formatter(&fx)
            .y_label_formatter(&fy)
            .x_desc("delta BIC (symmetric log scale: sign · log10(1 + |delta BIC|))")
            .draw()?;
        for (i, c) in bars.iter().enumerate() {
            let y = (n - 1 - i) as f64;
            let end = symlog(c.delta_bic);
            let colour = if c.supported {
                SUPPORTED
            } else {
                NOT_SUPPORTED
            };
            chart.draw_series(std::iter::once(Rectangle::new(
                [(0.0, y + 0.15), (end, y + 0.85)],
                colour.filled(),
            )))?;
            chart.draw_series(std::iter::once(Text::new(
                num(c.delta_bic),
                (end.max(0.0) + 0.01 * width, y + 0.75),
                ("sans-serif", 13).into_font(),
            )))?;
        }
        for x in [0.0, symlog(support)] {
            chart.draw_series(LineSeries::new(
                [(x, 0.0), (x, n as f64)],
                GREY.stroke_width(2),
            ))?;
        }
        Ok(())
    })?;
    Ok(Some(out))
}

/// A parameter's value ± its uncertainty: the delay in µs, a ratio unit
/// (`k_ae_per_g`) as a plain number (its name says the unit), else as the statistics
/// report writes it.
fn param_value(p: &ParamOut) -> String {
    if p.kind == DELAY_KIND && p.name == "delay_s" {
        delay_in_us(p.value, p.sigma, "±", "µs")
    } else if p.name.contains("_per_") {
        value_pm("", p.value, p.sigma)
    } else {
        value_pm(&p.name, p.value, p.sigma)
    }
}

/// The parameters as a table (effect, unit, parameter, value ± sigma, sigma from the
/// white-noise covariance).
fn params_table(h: &mut String, params: &[ParamOut]) {
    h.push_str(
        "<table><tr><th>effect</th><th>unit</th><th>parameter</th>\
         <th>value ± standard uncertainty (sandwich)</th><th>sigma if the noise were white</th></tr>",
    );
    for p in params {
        let white = ParamOut {
            sigma: p.sigma_white,
            ..p.clone()
        };
        // The uncertainty part of the same form, so that its prefix and decimals are
        // the value's.
        let white = param_value(&white);
        let white = white.split_once('±').map_or("n/a", |(_, s)| s.trim());
        let _ = write!(
            h,
            "<tr><td class=l>{}</td><td>{}</td><td class=l>{}</td><td>{}</td><td>{}</td></tr>",
            esc(&p.kind),
            p.unit.map_or("all".to_string(), |u| u.to_string()),
            esc(&p.name),
            esc(&param_value(p)),
            esc(white)
        );
    }
    h.push_str("</table>");
}

/// The correlations of the final fit's parameters, shaded by size.
fn correlation_table(h: &mut String, params: &[ParamOut], correlation: &[Vec<f64>]) {
    if params.len() < 2 || correlation.len() != params.len() {
        return;
    }
    h.push_str("<h3>Correlations between the parameters</h3><table><tr><th></th>");
    for p in params {
        let _ = write!(h, "<th>{}.{}</th>", esc(&p.kind), esc(&p.name));
    }
    h.push_str("</tr>");
    for (i, p) in params.iter().enumerate() {
        let _ = write!(h, "<tr><th class=l>{}.{}</th>", esc(&p.kind), esc(&p.name));
        for j in 0..params.len() {
            let r = correlation[i].get(j).copied().unwrap_or(f64::NAN);
            let (shade, text) = if r.is_finite() {
                ((255.0 - 120.0 * r.abs()).round() as u8, format!("{r:+.3}"))
            } else {
                (255, "n/a".into())
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

/// The verdict in words, for the top of the page.
fn verdict_html(d: &WaveDiagnosis) -> String {
    let (before, after) = (&d.lack_of_fit_before, &d.lack_of_fit);
    let z_noise = num(d.options.z_noise);
    let code = |k: &[String]| {
        k.iter()
            .map(|k| format!("<code>{}</code>", esc(k)))
            .collect::<Vec<_>>()
            .join(" + ")
    };
    let mut h = match d.verdict.as_str() {
        "noise" => format!(
            "<b>Noise: the model as is predicts the readings within their noise</b> (lack of \
             fit z {} &lt; {z_noise}): no effect is missing that these logs can see.",
            num(after.z)
        ),
        "effect" => format!(
            "<b>Missing effect{}: {}</b>. With {} the lack of fit z falls from {} to {} \
             (&lt; {z_noise}); chi2 per vibrating reading {}.",
            if d.found.len() > 1 { "s" } else { "" },
            code(&d.found),
            if d.found.len() > 1 { "them" } else { "it" },
            num(before.z),
            num(after.z),
            num(d.chi2_per_dof)
        ),
        "confounded" => format!(
            "{}<b>Confounded: {} explain the residual equally well</b> (delta BIC within {}): \
             these logs cannot tell them apart.",
            if d.found.is_empty() {
                String::new()
            } else {
                format!("Found first: {}. ", code(&d.found))
            },
            d.confounded
                .iter()
                .map(|k| format!("<code>{}</code>", esc(k)))
                .collect::<Vec<_>>()
                .join(" and "),
            num(d.options.bic_tie)
        ),
        _ if d.found.is_empty() => format!(
            "<b>Unexplained structure</b>: the lack of fit z {} (≥ {z_noise}) remains and no \
             candidate of the library is supported.",
            num(after.z)
        ),
        _ => format!(
            "<b>Found {}, but structure remains unexplained</b>: the lack of fit z falls from \
             {} to {} (≥ {z_noise}); chi2 per vibrating reading {}.",
            code(&d.found),
            num(before.z),
            num(after.z),
            num(d.chi2_per_dof)
        ),
    };
    for (kind, unit, ps) in effect_groups(&d.params) {
        let values: Vec<String> = ps
            .iter()
            .map(|p| format!("{} = {}", esc(&p.name), esc(&param_value(p))))
            .collect();
        let on = unit.map_or(String::new(), |u| format!(" (unit {u})"));
        let _ = write!(
            h,
            "<br><code>{}</code>{on}: {}",
            esc(&kind),
            values.join(", ")
        );
    }
    if let Some(p) = fitted_delay(d) {
        let _ = write!(h, "<br>sensors' delay (fitted): {}", esc(&param_value(p)));
    }
    h
}

/// The RMS over the vibrating readings (all units) of residuals, g.
fn rms_vibrating_g(rs: &[RunResidual]) -> f64 {
    let (s, n) = rs
        .iter()
        .flat_map(|r| r.residual_g.iter().zip(&r.quiet))
        .filter(|(_, q)| !**q)
        .flat_map(|(x, _)| x.iter())
        .filter(|x| x.is_finite())
        .fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    if n > 0 {
        (s / n as f64).sqrt()
    } else {
        f64::NAN
    }
}

/// The page's head and style, as the statistics report's.
const STYLE: &str = "<style>body{font-family:sans-serif;margin:24px;max-width:1340px}\
     table{border-collapse:collapse;margin:6px 0}td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}\
     .l{text-align:left}.verdict{background:#f3f6fb;border-left:6px solid #1f77b4;padding:10px 14px;font-size:17px}\
     .row{display:flex;gap:8px;margin-bottom:6px}pre{background:#f6f6f6;padding:8px;overflow-x:auto}\
     h2{margin-top:28px}</style>";

/// The overview: path, data, model, the lack of fit before and after, the noise and
/// the runs.
fn overview(h: &mut String, d: &WaveDiagnosis, model: &LabModel) {
    let given = model.effect_kinds();
    let _ = write!(
        h,
        "<p>Evaluation path: <b>waveform</b> (every accelerometer reading predicted from the \
         vibration sensors' samples through the model). Data: {} log{} ({}). Model as given: \
         {} mode, effects: {}. Effects found by the lab: {}.</p>",
        d.runs.len(),
        if d.runs.len() == 1 { "" } else { "s" },
        esc(&d
            .runs
            .iter()
            .map(|r| r.log.as_str())
            .collect::<Vec<_>>()
            .join(", ")),
        model.mode.name(),
        esc(&if given.is_empty() {
            "none".into()
        } else {
            given.join(", ")
        }),
        esc(&if d.found.is_empty() {
            "none".into()
        } else {
            d.found.join(", ")
        })
    );
    h.push_str(
        "<table><tr><th></th><th>chi2 per reading, vibrating</th><th>chi2 per reading, quiet</th>\
         <th>lack of fit z</th><th>vibrating readings</th><th>quiet readings</th></tr>",
    );
    for (name, l) in [
        ("before (model as is)", &d.lack_of_fit_before),
        ("after (final model)", &d.lack_of_fit),
    ] {
        let _ = write!(
            h,
            "<tr><th class=l>{name}</th><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            num(l.chi2_per_reading_vibrating),
            num(l.chi2_per_reading_quiet),
            num(l.z),
            l.vibrating,
            l.quiet
        );
    }
    let _ = write!(
        h,
        "</table><p>A right model: chi2 per reading 1 and z below {} (the z compares the \
         vibrating readings' residual with the quiet ones' from block means; correlation \
         inflation {}).</p>",
        num(d.options.z_noise),
        num(d.lack_of_fit.inflation)
    );
    let _ = write!(
        h,
        "<h3>Noise per reading</h3><p>{}</p><table><tr><th>unit</th><th>noise (1 sigma)</th></tr>",
        if d.noise.from_quiet {
            "From the quiet readings (the sensors' and the readings' own noise, independent of \
             the model's fit under vibration)."
        } else {
            "From the fit's own residual: too few quiet readings to measure it apart."
        }
    );
    for (u, s) in d.noise.sigma_g.iter().enumerate() {
        let _ = write!(h, "<tr><td>{u}</td><td>{}</td></tr>", eng(*s, "g"));
    }
    h.push_str(
        "</table><h3>Runs</h3><table><tr><th class=l>log</th><th>readings</th><th>used</th><th>quiet</th>\
         <th>uncovered</th><th>missing</th><th>no reference</th><th>delay</th><th>band</th>\
         <th>passports from</th></tr>",
    );
    for r in &d.runs {
        let _ = write!(
            h,
            "<tr><td class=l>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>\
             <td>{}</td><td>{} ({})</td><td>{} – {}</td><td class=l>{}</td></tr>",
            esc(&r.log),
            r.counts.readings,
            r.counts.used,
            r.counts.quiet,
            r.counts.uncovered,
            r.counts.missing,
            r.counts.no_reference,
            eng(r.delay_s, "s"),
            if r.delay_stated { "stated" } else { "fitted" },
            eng(r.band_hz.0, "Hz"),
            eng(r.band_hz.1, "Hz"),
            esc(&r.passports_from)
        );
    }
    h.push_str("</table>");
}

/// A round's candidates as a table, best first: the ones that could not be fitted
/// with their error.
fn round_table(h: &mut String, step: &StepOut) {
    let mut cands: Vec<&CandidateOut> = step.candidates.iter().collect();
    cands.sort_by(|a, b| a.delta_bic.total_cmp(&b.delta_bic));
    h.push_str(
        "<table><tr><th>candidate</th><th>delta BIC</th><th>supported</th>\
         <th>parameters ± standard uncertainty</th></tr>",
    );
    for c in cands {
        let what = match &c.error {
            Some(e) => format!("not fitted: {}", esc(e)),
            None => c
                .params
                .iter()
                .map(|p| format!("{} = {}", esc(&p.name), esc(&param_value(p))))
                .collect::<Vec<_>>()
                .join(", "),
        };
        let _ = write!(
            h,
            "<tr><td class=l>{}</td><td>{}</td><td>{}</td><td class=l>{what}</td></tr>",
            esc(&candidate_label(c)),
            if c.error.is_some() {
                "–".to_string()
            } else {
                num(c.delta_bic)
            },
            if c.supported { "yes" } else { "no" }
        );
    }
    h.push_str("</table>");
}

/// The plots of the page, in order, each with its file name.
struct Plots(Vec<(String, String)>);

impl Plots {
    /// Adds a plot; returns its SVG, for the page.
    fn add(&mut self, file: String, svg: String) -> &str {
        self.0.push((file, svg));
        self.0.last().map_or("", |p| p.1.as_str())
    }
}

/// The residual of every reading along each run, before and after.
fn residual_section(h: &mut String, plots: &mut Plots, d: &WaveDiagnosis) -> Result<()> {
    let with_after = !d.found.is_empty();
    let _ = write!(
        h,
        "<h2>Residual of every reading along each run</h2><p>Reading minus prediction, one \
         strip per unit on its own scale; {} Vibrating readings in colour, quiet ones in grey; \
         green: ± 1 sigma of the unit's noise per reading. A run of more than {MAX_POINTS} \
         readings is drawn in blocks: each band spans its block's smallest to largest \
         residual, so every reading shows, and for noise alone it is wider than ± 1 sigma \
         (about ± 2.5 sigma at 100 readings a block): compare the vibrating readings with the \
         quiet ones beside them.</p>",
        if with_after {
            "left the model as is (its delay fitted when no log states it, red), right the \
             final model (blue)."
        } else {
            "the model as is (the lab found no effect: the final model is the same)."
        }
    );
    let after_name = format!("after (+ {})", d.found.join(" + "));
    for (i, before) in d.residuals_before.iter().enumerate() {
        h.push_str("<div class=row>");
        let title = format!("{}: before (model as is)", before.log);
        h.push_str(plots.add(
            format!("residual-run{i}-before.svg"),
            run_figure(&title, before, &d.noise.sigma_g, BEFORE)?,
        ));
        if let Some(after) = d.residuals.get(i).filter(|_| with_after) {
            let title = format!("{}: {after_name}", after.log);
            h.push_str(plots.add(
                format!("residual-run{i}-after.svg"),
                run_figure(&title, after, &d.noise.sigma_g, AFTER)?,
            ));
        }
        h.push_str("</div>");
    }
    Ok(())
}

/// The windows' mean residual along each run, two runs a row.
fn windows_section(h: &mut String, plots: &mut Plots, d: &WaveDiagnosis) -> Result<()> {
    if d.windows.is_empty() {
        return Ok(());
    }
    let ratio = d.window_residual_rms_g / d.window_noise_rms_g;
    let _ = write!(
        h,
        "<h2>Mean residual of {} s windows (final model)</h2><p>Over the vibrating windows \
         the mean residual's RMS is {}, against {} over the quiet windows (the noise's own \
         level at this length): ratio {}.</p>",
        num(d.options.window_s),
        eng(d.window_residual_rms_g, "g"),
        eng(d.window_noise_rms_g, "g"),
        num(ratio)
    );
    let mut figures: Vec<String> = Vec::new();
    for (i, run) in d.runs.iter().enumerate() {
        let ws: Vec<&WindowOut> = d.windows.iter().filter(|w| w.run == i).collect();
        if ws.is_empty() {
            continue;
        }
        let svg = windows_figure(&run.log, &ws, d.window_noise_rms_g, d.options.window_s)?;
        figures.push(plots.add(format!("windows-run{i}.svg"), svg).to_string());
    }
    for pair in figures.chunks(2) {
        let _ = write!(h, "<div class=row>{}</div>", pair.concat());
    }
    Ok(())
}

/// Each round's candidates: a plot and a table.
fn rounds_section(h: &mut String, plots: &mut Plots, d: &WaveDiagnosis) -> Result<()> {
    let rounds: Vec<(usize, &StepOut)> = d
        .steps
        .iter()
        .enumerate()
        .skip(1)
        .filter(|(_, s)| !s.candidates.is_empty())
        .collect();
    if rounds.is_empty() {
        return Ok(());
    }
    let _ = write!(
        h,
        "<h2>The search, round by round</h2><p>Each round fits every candidate beside the \
         effects found so far (all their parameters free); its delta BIC is against the \
         model of the round, the chi2 divided by the residual's correlation inflation. The \
         best candidate is added when its delta BIC is at most {}.</p>",
        num(d.options.bic_support)
    );
    for (i, step) in rounds {
        let base = d.found.get(..i - 1).unwrap_or(&d.found);
        let against = if base.is_empty() {
            "the model as is".to_string()
        } else {
            format!("the model + {}", base.join(" + "))
        };
        let added = step
            .added
            .as_deref()
            .map_or("nothing added".to_string(), |a| format!("added {a}"));
        let title = format!("round {i}: candidates against {against} ({added})");
        let _ = write!(h, "<h3>{}</h3>", esc(&title));
        if let Some(svg) = round_figure(&title, step, d.options.bic_support)? {
            h.push_str(plots.add(format!("round{i}.svg"), svg));
        }
        round_table(h, step);
    }
    Ok(())
}

/// Draws the report of a diagnosis on the waveform (module doc); `model` is the model
/// as given (the diagnosis holds the final one). Its summary's `rms_before_g` and
/// `rms_after_g` are the RMS of the vibrating readings' residual (every unit), its
/// `noise_floor_g` the RMS over the units of the noise per reading, and its
/// `time_units` the three units.
pub fn render_waveform(d: &WaveDiagnosis, model: &LabModel) -> Result<Report> {
    let mut plots = Plots(Vec::new());
    let mut h = String::new();
    let _ = write!(
        h,
        "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>vibrocomp lab report \
         (waveform): {}</title>{STYLE}</head><body><h1>vibrocomp lab report (waveform)</h1>",
        esc(&d
            .runs
            .iter()
            .map(|r| r.log.as_str())
            .collect::<Vec<_>>()
            .join(", "))
    );
    let _ = write!(h, "<div class=verdict>{}</div>", verdict_html(d));
    overview(&mut h, d, model);
    if !d.params.is_empty() {
        h.push_str("<h2>Parameters of the final model</h2>");
        params_table(&mut h, &d.params);
        correlation_table(&mut h, &d.params, &d.correlation);
    }
    residual_section(&mut h, &mut plots, d)?;
    windows_section(&mut h, &mut plots, d)?;
    rounds_section(&mut h, &mut plots, d)?;
    let _ = writeln!(
        h,
        "<h2>The diagnosis in full</h2><pre>{}</pre></body></html>",
        esc(&{
            let mut text = String::new();
            wave_text::write_wave_diagnosis(&mut text, d);
            text
        })
    );
    let noise_floor_g = (d.noise.sigma_g.iter().map(|s| s * s).sum::<f64>() / 3.0).sqrt();
    let summary = ReportSummary {
        plots: plots.0.len(),
        ladder: Vec::new(),
        rms_before_g: rms_vibrating_g(&d.residuals_before),
        rms_after_g: rms_vibrating_g(&d.residuals),
        effects_added: d.found.clone(),
        noise_floor_g,
        variables: vec!["t_s".into()],
        time_units: (0..3).map(|u| format!("unit {u}")).collect(),
    };
    Ok(Report {
        index_html: h,
        plots: plots.0,
        summary,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wave_text::fixture::{diagnosis, residual};
    use crate::BaseMode;

    fn size(r: &Report) -> usize {
        r.index_html.len() + r.plots.iter().map(|p| p.1.len()).sum::<usize>()
    }

    #[test]
    fn the_page_holds_the_plots_and_the_values() {
        let d = diagnosis(2, 2000);
        let r = render_waveform(&d, &LabModel::base(BaseMode::Exact)).unwrap();
        let h = &r.index_html;
        assert!(h.contains("vibrocomp lab report (waveform)"));
        assert!(h.contains("Evaluation path: <b>waveform</b>"));
        assert!(
            h.contains("Missing effect: <code>mount_resonance</code>"),
            "verdict"
        );
        // The frequency to the uncertainty's second digit, the delay in µs.
        assert!(h.contains("48.0123 ± 0.0021 Hz"), "a parameter ± sigma");
        assert!(h.contains("1250.3 ± 2.1 µs"), "the delay");
        // z before and after, the noise per unit.
        assert!(h.contains("<td>35.2</td>") && h.contains("<td>0.8000</td>"));
        assert!(h.contains("12.3 µg") && h.contains("From the quiet readings"));
        // The candidate that failed, listed as text.
        assert!(h.contains("not fitted: heating: no start"));
        assert!(h.contains("<pre>path: waveform"));
        // Per run: before, after and windows; and the two rounds.
        let names: Vec<&str> = r.plots.iter().map(|p| p.0.as_str()).collect();
        assert_eq!(
            names,
            [
                "residual-run0-before.svg",
                "residual-run0-after.svg",
                "residual-run1-before.svg",
                "residual-run1-after.svg",
                "windows-run0.svg",
                "windows-run1.svg",
                "round1.svg",
                "round2.svg",
            ]
        );
        for (_, svg) in &r.plots {
            assert!(svg.starts_with("<svg"), "{}", &svg[..80.min(svg.len())]);
            assert!(h.contains(svg.as_str()), "every plot inline");
        }
        assert_eq!(r.summary.plots, 8);
        assert_eq!(r.summary.effects_added, ["mount_resonance"]);
        // The vibrating readings' residual before: the 200 ug sine on two units of
        // three (RMS 200/sqrt(2) ug each) over noise.
        assert!(r.summary.rms_before_g > 100e-6 && r.summary.rms_before_g < 130e-6);
        assert!(r.summary.rms_after_g < 10e-6);
    }

    #[test]
    fn nan_residuals_are_skipped() {
        let r = residual("a.mcap", 50, 1e-4);
        let tr = trace(&r, 0);
        assert_eq!(tr.per, 1);
        // Reading 5 is NaN: 49 points, none of them NaN.
        assert_eq!(tr.vibrating.len() + tr.quiet.len(), 49);
        assert!(tr
            .vibrating
            .iter()
            .chain(&tr.quiet)
            .all(|b| b.lo_ug.is_finite() && b.t0_s.is_finite()));
        assert!(!tr
            .vibrating
            .iter()
            .chain(&tr.quiet)
            .any(|b| b.t0_s == 5.0 / 400.0));
        // A run all NaN draws nothing and still renders.
        let mut d = diagnosis(1, 100);
        for x in d.residuals[0].residual_g.iter_mut() {
            *x = [f64::NAN; 3];
        }
        let report = render_waveform(&d, &LabModel::base(BaseMode::Exact)).unwrap();
        assert!(!report.index_html.contains("NaN"));
    }

    #[test]
    fn blocks_keep_every_reading_s_extremes() {
        let mut r = residual("a.mcap", 19_200, 0.0);
        r.residual_g[10_001][1] = 1e-3;
        let tr = trace(&r, 1);
        assert_eq!(tr.per, 19_200usize.div_ceil(MAX_BLOCKS));
        assert!(tr.vibrating.len() + tr.quiet.len() <= MAX_BLOCKS + 2);
        let max = tr
            .vibrating
            .iter()
            .chain(&tr.quiet)
            .map(|b| b.hi_ug)
            .fold(f64::NEG_INFINITY, f64::max);
        assert!((max - 1000.0).abs() < 1e-9, "the outlier shows: {max}");
        // Vibrating blocks form one stretch (the run's middle half).
        assert_eq!(
            tr.vibrating.chunk_by(|a, b| b.chunk == a.chunk + 1).count(),
            1
        );
    }

    #[test]
    fn a_long_log_gives_a_bounded_report() {
        let d = diagnosis(8, 19_200);
        let r = render_waveform(&d, &LabModel::base(BaseMode::Exact)).unwrap();
        let total = size(&r);
        assert!(total < 10_000_000, "{total} bytes");
        // The largest a run is drawn point by point: the heaviest figures.
        let worst = size(
            &render_waveform(&diagnosis(8, MAX_POINTS), &LabModel::base(BaseMode::Exact)).unwrap(),
        );
        assert!(worst < 5_000_000, "{worst} bytes");
        // And no larger than a log ten times shorter by more than a little: the
        // blocks, not the readings, set the size.
        let small =
            size(&render_waveform(&diagnosis(8, 1_920), &LabModel::base(BaseMode::Exact)).unwrap());
        assert!(total < 3 * small, "{total} against {small}");
    }

    #[test]
    fn the_symmetric_log_is_its_inverse_s() {
        for x in [-1234.5, -10.0, 0.0, 3.0, 1e6] {
            assert!((symlog_inv(symlog(x)) - x).abs() < 1e-9 * x.abs().max(1.0));
        }
        assert!((symlog(99.0) - 2.0).abs() < 1e-12);
        assert!((symlog(-9.0) + 1.0).abs() < 1e-12);
    }
}
