//! `vibrocomp identify measure`: the VE of one run by [P2 (16)] (MODEL.md section 8),
//! from the records of a CSV (`phase,u_v` or `still1_v,vib_v,still2_v`) or from a rig's
//! own time-stamped readings (`time_s` first; the windows on its time), with the unit's
//! linear response to the table's motion removed through a reference accelerometer
//! (`--reference`). The flags are checked first, every problem at once, before any file
//! is read; the reading and the maths are `vibro_ident::report::measure_file` and
//! `vibro_ident::rig::measure_timed_file`. See docs/identification.md.

use clap::Args;
use std::path::PathBuf;
use vibro_ident::reference::LinearFit;
use vibro_ident::rig::{TimedRequest, TimedRequestRaw};
use vibro_ident::{MeasureOptions, Phase, VeMeasurement};
use vibro_service::ServiceConfig;

use super::identify::{load_passport, value_pm};
use crate::output::{fmt_g, print_json};

#[derive(Debug, Args)]
pub struct MeasureArgs {
    /// CSV of the unit's output. Records: columns `phase` (still1 | vib | still2) and
    /// `u_v`, one sample a row; or three columns `still1_v, vib_v, still2_v` (empty
    /// cells allowed where a record is shorter). A rig's own readings: `time_s` first,
    /// then the outputs in V (`--column`), the windows given by `--still-before-s`,
    /// `--vibrating-s`, `--still-after-s`. `#` starts a comment line.
    pub file: PathBuf,
    /// Passport file, or the id of a shipped one; gives K1 (and, with `--reference`,
    /// the linear response k1, m1, m2).
    #[arg(long)]
    pub passport: String,
    /// Batches per record for the batch-means standard error.
    #[arg(long, default_value_t = 20)]
    pub batches: usize,
    /// Largest accepted tilt of the input axis during the run, rad ([P2]: 1e-4).
    #[arg(long, default_value_t = 1e-4, allow_negative_numbers = true)]
    pub tilt_limit_rad: f64,
    /// A rig's readings: the unit's output column of FILE, V (e.g. u3_v).
    #[arg(long)]
    pub column: Option<String>,
    /// A rig's readings: the still window before vibration, FROM,TO on FILE's time, s.
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub still_before_s: Option<Vec<f64>>,
    /// A rig's readings: the vibrating window, FROM,TO in s (leave the ramps out).
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub vibrating_s: Option<Vec<f64>>,
    /// A rig's readings: the still window after vibration, FROM,TO in s.
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub still_after_s: Option<Vec<f64>>,
    /// A rig's readings: the DC-coupled reference accelerometer on the table (`time_s`
    /// first, body x, y, z in g). The unit's linear response to the table's motion is
    /// fitted through it and removed, so the uncertainty states the VE's own scatter;
    /// without it the batch means carry that response and overstate it.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// With `--reference`: the rig file (docs/logs.md, "A rig's own data") whose
    /// `[reference.chain]` states the reference's chain (an AC-coupled piezoelectric
    /// reference in V: sensitivity, AC corner, delay) and whose `[reference]` states the
    /// orientation its gravity comes from. The chain is undone before the fit.
    #[arg(long)]
    pub rig: Option<PathBuf>,
    /// With `--reference`: its body x, y, z columns, g (default: ax_g,ay_g,az_g; with
    /// `--rig`: ax_v,ay_v,az_v in V).
    #[arg(long, value_delimiter = ',')]
    pub reference_columns: Option<Vec<String>>,
    /// With `--reference`: the unit's input axis in the body frame: x, +y, -z or a unit
    /// vector X,Y,Z.
    #[arg(long, allow_hyphen_values = true)]
    pub ia: Option<String>,
    /// With `--reference`: the unit's output axis in the body frame (with `--pa`: the
    /// passport's cross-axis terms m1, m2 join the response; default IA alone).
    #[arg(long, allow_hyphen_values = true)]
    pub oa: Option<String>,
    /// With `--reference`: the unit's pendulum axis in the body frame (with `--oa`).
    #[arg(long, allow_hyphen_values = true)]
    pub pa: Option<String>,
    /// With `--reference`: the top of the fitted response, Hz (default: the shipped
    /// estimator's broadband top, as `identify campaign`); at most 0.45 times the
    /// reference's rate is used.
    #[arg(long, allow_negative_numbers = true)]
    pub response_top_hz: Option<f64>,
    /// Print the result as JSON.
    #[arg(long)]
    pub json: bool,
}

/// The flags, validated: what to measure.
enum Request {
    /// The records of a `phase,u_v` or `still1_v,vib_v,still2_v` file.
    Records(MeasureOptions),
    /// A rig's time-stamped readings.
    Timed(Box<TimedRequest>),
}

/// The flags the library's rule keys stand for (`vibro_ident::rig::TimedRequest::problems`).
const KEY_FLAGS: [(&str, &str); 12] = [
    ("rig", "--rig"),
    ("still_before_s", "--still-before-s"),
    ("vibrating_s", "--vibrating-s"),
    ("still_after_s", "--still-after-s"),
    ("reference_columns", "--reference-columns"),
    ("column", "--column"),
    ("ia", "--ia"),
    ("oa", "--oa"),
    ("pa", "--pa"),
    ("response_top_hz", "--response-top-hz"),
    ("batches", "--batches"),
    ("tilt_limit_rad", "--tilt-limit-rad"),
];

/// A library problem (`key = value: rule`, `key: rule`, `key's end`) with each key
/// spelt as its flag.
fn as_flags(problem: &str) -> String {
    let mut out = String::with_capacity(problem.len() + 16);
    let mut rest = problem;
    // A key starts a word: not after a letter, digit, `_` or `-`.
    let mut at_word = true;
    'scan: while !rest.is_empty() {
        if at_word {
            for (key, flag) in KEY_FLAGS {
                if let Some(after) = rest.strip_prefix(key) {
                    if [" = ", "'s ", ": "].iter().any(|p| after.starts_with(p)) {
                        out.push_str(flag);
                        rest = after;
                        at_word = false;
                        continue 'scan;
                    }
                }
            }
        }
        let mut chars = rest.chars();
        if let Some(c) = chars.next() {
            out.push(c);
            at_word = !(c.is_alphanumeric() || c == '_' || c == '-');
        }
        rest = chars.as_str();
    }
    out
}

/// The flags checked and turned into a request: every problem at once.
fn request(args: &MeasureArgs) -> anyhow::Result<Request> {
    let mut problems: Vec<String> = Vec::new();
    let options = MeasureOptions {
        n_batches: args.batches,
        tilt_limit_rad: args.tilt_limit_rad,
    };
    let timed = args.column.is_some()
        || [&args.still_before_s, &args.vibrating_s, &args.still_after_s]
            .iter()
            .any(|w| w.is_some());
    let rig_only = [
        ("--reference", args.reference.is_some()),
        ("--reference-columns", args.reference_columns.is_some()),
        ("--ia", args.ia.is_some()),
        ("--oa", args.oa.is_some()),
        ("--pa", args.pa.is_some()),
        ("--response-top-hz", args.response_top_hz.is_some()),
        ("--rig", args.rig.is_some()),
    ];
    if !timed {
        for (flag, given) in rig_only {
            if given {
                problems.push(format!(
                    "{flag}: applies to a rig's time-stamped readings: give --column and the \
                     windows --still-before-s, --vibrating-s, --still-after-s"
                ));
            }
        }
        problems.extend(options.problems().iter().map(|p| as_flags(p)));
        finish(problems)?;
        return Ok(Request::Records(options));
    }
    let raw = TimedRequestRaw {
        file: args.file.clone(),
        column: args.column.clone(),
        still_before_s: args.still_before_s.clone(),
        vibrating_s: args.vibrating_s.clone(),
        still_after_s: args.still_after_s.clone(),
        reference: args.reference.clone(),
        reference_columns: args.reference_columns.clone(),
        ia: args.ia.clone(),
        oa: args.oa.clone(),
        pa: args.pa.clone(),
        response_top_hz: args.response_top_hz,
        reference_chain: match &args.rig {
            None => None,
            Some(rig) => Some(vibro_ident::chain::ReferenceChainRequest::from_rig(
                &vibro_config::load_rig(rig)?,
            )?),
        },
        options,
    };
    // As `identify campaign`: the shipped estimator's broadband top.
    let default_top_hz = vibro_estimator::Config::shipped()?
        .estimator
        .raw()
        .broadband_band_hz[1];
    match raw.validate(default_top_hz) {
        Ok(request) => Ok(Request::Timed(Box::new(request))),
        Err(vibro_ident::Error::Request { problems }) => {
            Err(bad_values(problems.iter().map(|p| as_flags(p)).collect()))
        }
        Err(e) => Err(e.into()),
    }
}

fn finish(problems: Vec<String>) -> anyhow::Result<()> {
    match problems.is_empty() {
        true => Ok(()),
        false => Err(bad_values(problems)),
    }
}

/// Every problem of the flags, one per line.
fn bad_values(problems: Vec<String>) -> anyhow::Error {
    match problems.as_slice() {
        [one] => anyhow::anyhow!("{one}"),
        _ => anyhow::anyhow!(
            "{} bad values:\n  {}",
            problems.len(),
            problems.join("\n  ")
        ),
    }
}

pub fn run(args: MeasureArgs) -> anyhow::Result<()> {
    let request = request(&args)?;
    let passport = load_passport(&args.passport)?;
    let options = match request {
        Request::Records(options) => options,
        Request::Timed(request) => {
            let report = vibro_ident::rig::measure_timed_file(&request, &passport)?;
            if args.json {
                return print_json(&report);
            }
            return print_timed(&report);
        }
    };
    let report = vibro_ident::measure_file(&args.file, &passport, &options)?;
    if args.json {
        return print_json(&report);
    }
    outln!(
        "VE measured from {} by [P2 (16)], passport {} (K1 = {} V/g)",
        report.file,
        report.passport,
        report.measurement.k1_v_per_g
    )?;
    outln!()?;
    print_measurement(&report.measurement)
}

/// The records' means, the VE and the tilt check.
fn print_measurement(m: &VeMeasurement) -> anyhow::Result<()> {
    outln!(
        "{:<8} {:>8}  {:>18}  {:>23}",
        "record",
        "samples",
        "mean",
        "std error (batch means)"
    )?;
    for (phase, r) in [
        (Phase::Still1, &m.still1),
        (Phase::Vib, &m.vib),
        (Phase::Still2, &m.still2),
    ] {
        outln!(
            "{:<8} {:>8}  {:>16.9} V  {:>20.3} uV",
            phase.to_string(),
            r.n_samples,
            r.mean_v,
            r.std_error_v * 1e6
        )?;
    }
    outln!()?;
    outln!(
        "dV = {}",
        value_pm(fmt_g(m.ve_g), Some(fmt_g(m.ve_sigma_g)))
    )?;
    outln!(
        "tilt check: |<U1> - <U3>|/|K1| = {} (limit {:e} g = {:e} rad): accepted",
        value_pm(fmt_g(m.drift_g), Some(fmt_g(m.drift_sigma_g))),
        m.tilt_limit_rad,
        m.tilt_limit_rad
    )?;
    Ok(())
}

/// The fitted response in one line: its knots and the range of its gain and phase.
fn describe_fit(fit: &LinearFit) -> String {
    let range = |v: &[f64]| {
        let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        (lo, hi)
    };
    let (g_lo, g_hi) = range(&fit.gain);
    let (p_lo, p_hi) = range(&fit.phase_deg);
    let (f_lo, f_hi) = range(&fit.knots_hz);
    format!(
        "{} knots {f_lo}..{f_hi:.0} Hz over {} readings: gain {g_lo:.4}..{g_hi:.4}, phase \
         {p_lo:.2}..{p_hi:.2} deg relative to the passport's",
        fit.knots_hz.len(),
        fit.readings
    )
}

fn print_timed(r: &vibro_ident::rig::TimedReport) -> anyhow::Result<()> {
    outln!(
        "VE measured from {} (column {}, {} readings at {:.1} Hz) by [P2 (16)], passport {} \
         (K1 = {} V/g)",
        r.file,
        r.column,
        r.readings,
        r.reading_rate_hz,
        r.passport,
        r.measurement.k1_v_per_g
    )?;
    let s = &r.segments;
    outln!(
        "windows: still {}..{} s, vibrating {}..{} s, still {}..{} s",
        s.still_before_s[0],
        s.still_before_s[1],
        s.vibrating_s[0],
        s.vibrating_s[1],
        s.still_after_s[0],
        s.still_after_s[1]
    )?;
    match (&r.reference, &r.linear_response) {
        (Some(reference), fit) => {
            let how = match fit {
                Some(fit) => format!("fitted through the reference ({})", describe_fit(fit)),
                None => "the passport's through the reference (the vibrating window holds too \
                         few readings for the fit)"
                    .to_string(),
            };
            outln!(
                "reference: {} ({:.1} Hz, columns {}); unit's IA {:?}{}",
                reference.file,
                reference.rate_hz,
                reference.columns.join(","),
                reference.axes.ia,
                if reference.cross_axis_terms {
                    ", OA and PA given (m1, m2 in the response)"
                } else {
                    " (IA alone: m1, m2 left out of the response; give --oa and --pa)"
                }
            )?;
            if let Some(c) = &reference.chain {
                outln!(
                    "reference chain undone ({}): {:?} V/g, AC corner {} Hz, delay {} s; \
                     gravity from the stated orientation",
                    c.source,
                    c.sensitivity_v_per_g,
                    c.ac_corner_hz,
                    c.delay_s
                )?;
            }
            outln!("linear response removed: {how}")?;
        }
        (None, _) => outln!(
            "linear response NOT removed (no --reference): under vibration the vibrating \
             record's batch means carry the unit's linear response to the table's motion, so \
             the uncertainty below includes it and can state many times the VE's scatter"
        )?,
    }
    outln!()?;
    print_measurement(&r.measurement)?;
    if let Some(raw) = &r.raw {
        outln!(
            "raw records (linear response left in): dV = {}",
            value_pm(fmt_g(raw.ve_g), Some(fmt_g(raw.ve_sigma_g)))
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn library_keys_are_spelt_as_flags() {
        assert_eq!(
            as_flags(
                "vibrating_s = [7, 15.9]: must start at or after still_before_s's end (8): \
                 still, vibrating, still, in that order"
            ),
            "--vibrating-s = [7, 15.9]: must start at or after --still-before-s's end (8): \
             still, vibrating, still, in that order"
        );
        assert_eq!(
            as_flags("ia = [0.0, 0.0, 1.0], oa = [0.0, 1.0, 0.0]: must be perpendicular"),
            "--ia = [0.0, 0.0, 1.0], --oa = [0.0, 1.0, 0.0]: must be perpendicular"
        );
        // Prose that holds a key's letters is left alone.
        assert_eq!(
            as_flags("column = \"time_s\": must name the unit's output column (V), not time_s"),
            "--column = \"time_s\": must name the unit's output column (V), not time_s"
        );
        assert_eq!(
            as_flags("reference_columns = [\"a\"]: must"),
            "--reference-columns = [\"a\"]: must"
        );
    }
}
