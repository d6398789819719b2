//! `vibrocomp estimate`: vibration estimates (tones, band RMS and PSD, covariance,
//! kurtosis) per window of a recorded 3-axis vibration-sensor stream. The DSP lives in
//! `vibro-dsp`; reading the CSV file as a stream of blocks and validating it (each
//! problem with its file, line, column, value and rule) in `vibro_log::samples`; this
//! module turns the flags into the estimator's configuration and prints one row per
//! window or, with `--json`, the full estimates. See docs/estimation.md.

use anyhow::{bail, Context};
use clap::{Args, ValueEnum};
use indicatif::ProgressBar;
use serde::Serialize;
use std::path::PathBuf;
use vibro_dsp::{Counters, Estimate, Estimator, EstimatorConfig, EstimatorConfigRaw};
use vibro_log::samples;

use crate::output::print_json;

/// Units of the file's samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Units {
    /// Acceleration in g.
    G,
    /// Sensor output in volts, converted to g with `--sensitivity-v-per-g`.
    V,
}

/// `vibro_dsp::DEFAULT_BROADBAND_BAND_HZ` in the form `--band-hz` takes (LO,HI), which
/// help shows as it is (`default_values_t` would show `20 2000`, which does not parse);
/// a unit test keeps the two equal.
const DEFAULT_BAND_HZ: &str = "20,2000";

#[derive(Debug, Args)]
pub struct EstimateArgs {
    /// CSV file: three columns (axes x, y, z), one sample a row, at `--rate-hz`. A
    /// first row of column names is allowed, and one opening with `time_s` (the rig's
    /// format, as `log import` reads it) adds a time column whose rows must be one
    /// sample period apart; blank lines and `#` comment lines are
    /// skipped. `nan`/`inf` cells are taken as bad samples, flagged and left out.
    pub file: PathBuf,
    /// Sample rate of the file.
    #[arg(long)]
    pub rate_hz: f64,
    /// Units of the samples.
    #[arg(long, value_enum, default_value_t = Units::G)]
    pub units: Units,
    /// Sensitivity per axis with `--units v`: S1,S2,S3 in V/g (one value: all axes).
    /// A negative value flips the axis.
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub sensitivity_v_per_g: Option<Vec<f64>>,
    /// Window length, s.
    #[arg(long, default_value_t = vibro_dsp::DEFAULT_WINDOW_S)]
    pub window_s: f64,
    /// Overlap of consecutive windows, as a fraction of the window (0 <= overlap < 1).
    #[arg(long, default_value_t = vibro_dsp::DEFAULT_OVERLAP_FRACTION)]
    pub overlap: f64,
    /// Largest number of tones per window (0: no tone detection).
    #[arg(long, default_value_t = vibro_dsp::DEFAULT_MAX_TONES)]
    pub max_tones: usize,
    /// Tone detection threshold: tone power over the local floor in a 1/window_s band, dB.
    #[arg(
        long,
        default_value_t = vibro_dsp::DEFAULT_TONE_SNR_THRESHOLD_DB,
        allow_negative_numbers = true
    )]
    pub snr_db: f64,
    /// Band where tones are looked for, LO,HI in Hz (default: all resolvable).
    #[arg(long, value_delimiter = ',')]
    pub tone_band_hz: Option<Vec<f64>>,
    /// Band of the broadband RMS, covariance and kurtosis, LO,HI in Hz.
    #[arg(long, value_delimiter = ',', default_value = DEFAULT_BAND_HZ)]
    pub band_hz: Vec<f64>,
    /// PSD bands, LO-HI in Hz, comma separated (default: RIG.md's random-vibration table).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "20-40,40-80,80-160,160-320,320-640"
    )]
    pub psd_bands_hz: Vec<String>,
    /// Welch segment length, s (Hann, 50% overlap).
    #[arg(long, default_value_t = vibro_dsp::DEFAULT_WELCH_SEGMENT_S)]
    pub welch_segment_s: f64,
    /// Corner of the sensors' AC coupling (first-order high-pass), Hz, divided out.
    #[arg(long)]
    pub ac_corner_hz: Option<f64>,
    /// Frequency-response correction table (CSV: frequency_hz, gain_x, gain_y, gain_z,
    /// phase_x_deg, phase_y_deg, phase_z_deg; measured / true), divided out.
    #[arg(long)]
    pub response: Option<PathBuf>,
    /// Full scale per axis in g (one value: all axes): samples at or over it flag the
    /// axis saturated.
    #[arg(long, value_delimiter = ',')]
    pub full_scale_g: Option<Vec<f64>>,
    /// Print the full estimates as JSON.
    #[arg(long)]
    pub json: bool,
}

/// What `--json` prints.
#[derive(Debug, Serialize)]
struct Report<'a> {
    file: String,
    units: Units,
    columns: [String; 3],
    rows: u64,
    config: &'a EstimatorConfigRaw,
    counters: Counters,
    estimates: Vec<Estimate>,
}

pub fn run(args: EstimateArgs) -> anyhow::Result<()> {
    let raw = config_from_args(&args)?;
    // The estimator service's configuration rules (`EstimatorConfig::try_from`), every
    // problem named by its flag as well as its key.
    let config = EstimatorConfig::try_from(raw.clone()).map_err(flag_problems)?;
    let mut estimator = Estimator::new(config);
    let mut bar: Option<ProgressBar> = None;
    let result = samples::estimate_stream_csv(&args.file, &mut estimator, &mut |done, total| {
        let template = "estimating {bar:40} {bytes}/{total_bytes} ({eta} left)";
        let bar = bar.get_or_insert_with(|| crate::output::progress_bar(total, template));
        bar.set_position(done)
    });
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    let s = result?;
    let (estimates, columns, rows) = (s.estimates, s.columns, s.rows);
    if args.json {
        return print_json(&Report {
            file: args.file.display().to_string(),
            units: args.units,
            columns,
            rows,
            config: &raw,
            counters: estimator.counters(),
            estimates,
        });
    }
    let mut out = std::io::stdout().lock();
    let file = args.file.display().to_string();
    let header = vibro_dsp::text::TableHeader {
        file: &file,
        rows,
        rate_hz: args.rate_hz,
        columns: &columns,
        units: match args.units {
            Units::G => "g",
            Units::V => "V",
        },
        window_s: args.window_s,
        overlap: args.overlap,
        band_hz: [args.band_hz[0], args.band_hz[1]],
    };
    match vibro_dsp::text::write_table(&mut out, &header, &estimates) {
        // The reader went away (`| head`): nothing left to tell it.
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => other.context("writing the table to stdout"),
    }
}

/// Turns the options into the estimator's raw configuration (validated later, all at once).
fn config_from_args(args: &EstimateArgs) -> anyhow::Result<EstimatorConfigRaw> {
    let three = |name: &str, v: &[f64]| -> anyhow::Result<[f64; 3]> {
        match v {
            [a] => Ok([*a; 3]),
            [a, b, c] => Ok([*a, *b, *c]),
            _ => bail!("--{name} = {v:?}: give one value (all axes) or three (x, y, z)"),
        }
    };
    let sensitivity = match (args.units, &args.sensitivity_v_per_g) {
        (Units::G, None) => [1.0; 3],
        (Units::G, Some(s)) => bail!(
            "--sensitivity-v-per-g = {s:?} given with --units g: the samples are already in g \
             (use --units v for volts)"
        ),
        (Units::V, None) => {
            bail!("--units v needs --sensitivity-v-per-g S1,S2,S3 to convert volts to g")
        }
        (Units::V, Some(s)) => three("sensitivity-v-per-g", s)?,
    };
    let pair = |name: &str, v: &[f64]| -> anyhow::Result<[f64; 2]> {
        match v {
            [lo, hi] => Ok([*lo, *hi]),
            _ => bail!("--{name} = {v:?}: give two values LO,HI in Hz"),
        }
    };
    let mut raw = EstimatorConfigRaw::new(args.rate_hz, sensitivity);
    raw.window_s = args.window_s;
    raw.overlap_fraction = args.overlap;
    raw.max_tones = args.max_tones;
    raw.tone_snr_threshold_db = args.snr_db;
    raw.tone_band_hz = args
        .tone_band_hz
        .as_deref()
        .map(|v| pair("tone-band-hz", v))
        .transpose()?;
    raw.broadband_band_hz = pair("band-hz", &args.band_hz)?;
    raw.psd_bands_hz = args
        .psd_bands_hz
        .iter()
        .map(|b| parse_band(b))
        .collect::<anyhow::Result<_>>()?;
    raw.welch_segment_s = args.welch_segment_s;
    raw.ac_corner_hz = args.ac_corner_hz;
    raw.full_scale_g = args
        .full_scale_g
        .as_deref()
        .map(|v| three("full-scale-g", v))
        .transpose()?;
    if let Some(path) = &args.response {
        raw.response = samples::read_response_table(path)?;
    }
    Ok(raw)
}

/// The configuration key each flag sets (`EstimatorConfigRaw`), for the problems of
/// `EstimatorConfig::try_from`.
const FLAG_OF_KEY: [(&str, &str); 13] = [
    ("sample_rate_hz", "--rate-hz"),
    ("sensitivity_raw_per_g", "--sensitivity-v-per-g"),
    ("full_scale_g", "--full-scale-g"),
    ("ac_corner_hz", "--ac-corner-hz"),
    ("window_s", "--window-s"),
    ("overlap_fraction", "--overlap"),
    ("max_tones", "--max-tones"),
    ("tone_snr_threshold_db", "--snr-db"),
    ("tone_band_hz", "--tone-band-hz"),
    ("broadband_band_hz", "--band-hz"),
    ("psd_bands_hz", "--psd-bands-hz"),
    ("welch_segment_s", "--welch-segment-s"),
    ("response", "--response"),
];

/// The estimator's configuration problems as `--flag: key = value: rule`, all at
/// once, the huge or tiny numbers the library prints in full (`1e300` as 301 digits)
/// in engineering form.
fn flag_problems(e: vibro_dsp::Error) -> anyhow::Error {
    let vibro_dsp::Error::InvalidConfig { problems } = e else {
        return anyhow::Error::new(e).context("checking the estimation options");
    };
    let lines: Vec<String> = problems
        .iter()
        .map(|text| {
            let text = shorten_numbers(text);
            let key_end = text
                .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
                .unwrap_or(text.len());
            match FLAG_OF_KEY.iter().find(|(key, _)| *key == &text[..key_end]) {
                Some((_, flag)) => format!("{flag}: {text}"),
                None => text,
            }
        })
        .collect();
    match lines.as_slice() {
        [one] => anyhow::anyhow!("{one}"),
        _ => anyhow::anyhow!("{} bad values:\n  {}", lines.len(), lines.join("\n  ")),
    }
}

/// Rewrites every number of more than 24 characters (a float printed in full) in
/// engineering form (`crate::output::fmt_num`).
fn shorten_numbers(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(start) = rest.find(|c: char| c.is_ascii_digit()) {
        let len = rest[start..]
            .find(|c: char| !(c.is_ascii_digit() || c == '.'))
            .unwrap_or(rest.len() - start);
        // A leading minus sign belongs to the number.
        let from = if start > 0 && rest.as_bytes()[start - 1] == b'-' {
            start - 1
        } else {
            start
        };
        let token = &rest[from..start + len];
        out.push_str(&rest[..from]);
        match token.parse::<f64>() {
            Ok(x) if token.len() > 24 => out.push_str(&crate::output::fmt_num(x)),
            _ => out.push_str(token),
        }
        rest = &rest[start + len..];
    }
    out.push_str(rest);
    out
}

fn parse_band(text: &str) -> anyhow::Result<[f64; 2]> {
    vibro_dsp::parse_band_hz(text).with_context(|| {
        format!("--psd-bands-hz: {text:?}: a band is LO-HI in Hz with two numbers, e.g. 20-40")
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_band_flag_default_is_the_library_default() {
        let parsed: Vec<f64> = DEFAULT_BAND_HZ
            .split(',')
            .map(|x| x.parse().unwrap())
            .collect();
        assert_eq!(parsed, vibro_dsp::DEFAULT_BROADBAND_BAND_HZ);
    }

    #[test]
    fn psd_bands_parse_as_lo_hi() {
        assert_eq!(parse_band(" 20-40 ").unwrap(), [20.0, 40.0]);
        assert!(parse_band("20..40")
            .unwrap_err()
            .to_string()
            .contains("LO-HI"));
    }
}
