//! `vibrocomp identify`: shake-table identification of the VE components from test
//! positions (MODEL.md section 9) and measurement of the VE from still / vibrating /
//! still records (section 8). The maths lives in `vibro-ident`; this module reads the
//! CSV files, validates them (every problem at once, each with its line, column, value
//! and rule) and prints a table or `--json`. See docs/identification.md.

use anyhow::{bail, Context};
use clap::{Args, Subcommand, ValueEnum};
use serde::Serialize;
use std::path::{Path, PathBuf};
use vibro_ident::{
    Amplitudes, CoefficientEstimate, ComponentsEstimate, MeasureOptions, PassportTerms, Phase,
    TestPosition, UncertaintyBasis, VeMeasurement, VePrediction, WlsOptions,
};
use vibro_physics::passport::Passport;

use crate::output::{fmt_g, print_json};

#[derive(Debug, Subcommand)]
pub enum IdentifyCommand {
    /// VE components from a CSV of test positions (MODEL.md section 9, [P1 (21)-(23)]).
    Positions(PositionsArgs),
    /// The VE measured from still / vibrating / still records (MODEL.md section 8, [P2 (16)]).
    Measure(MeasureArgs),
}

/// Identification method(s).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum MethodArg {
    /// The paper's closed form (22): the ten standard positions only.
    ClosedForm,
    /// Weighted least squares of the six components: any positions at one amplitude.
    Wls,
    /// Closed form and WLS side by side; a method that does not apply is skipped
    /// with its reason.
    Both,
    /// WLS of the passport terms (c_asym, k2..k5, m31, m32): positions at any
    /// amplitudes (two or more IA amplitudes), components evaluated at `--at-ab3-g`.
    Coefficients,
}

#[derive(Debug, Args)]
pub struct PositionsArgs {
    /// CSV of test positions: tp, angle_deg, aB3_g, aB1_g, aB2_g, u_still_v, u_vib_v
    /// and optionally u_sigma_v (standard uncertainty of dU); `#` starts a comment line.
    pub file: PathBuf,
    /// Passport file, or the id of a shipped one (AL-15, AL-1M, AKS-05); gives K1.
    #[arg(long)]
    pub passport: String,
    /// Identification method(s).
    #[arg(long, value_enum, default_value_t = MethodArg::Both)]
    pub method: MethodArg,
    /// Flight accelerations along IA at which to predict the VE by (23), g.
    #[arg(long = "at-g", num_args = 1.., allow_negative_numbers = true, default_values_t = vec![1.0, 10.0])]
    pub at_g: Vec<f64>,
    /// `--method coefficients`: IA amplitude at which to give the components, g
    /// (default: the largest IA amplitude among the positions).
    #[arg(long)]
    pub at_ab3_g: Option<f64>,
    /// `--method coefficients`: OA amplitude for d0(2), g (default: as IA, as in TP9).
    #[arg(long)]
    pub at_ab1_g: Option<f64>,
    /// `--method coefficients`: PA amplitude for d0(3), g (default: as IA, as in TP10).
    #[arg(long)]
    pub at_ab2_g: Option<f64>,
    /// Print the full results as JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct MeasureArgs {
    /// CSV of output samples: columns `phase` (still1 | vib | still2) and `u_v`, one
    /// sample a row; or three columns `still1_v, vib_v, still2_v` (empty cells allowed
    /// where a record is shorter). `#` starts a comment line.
    pub file: PathBuf,
    /// Passport file, or the id of a shipped one; gives K1.
    #[arg(long)]
    pub passport: String,
    /// Batches per record for the batch-means standard error.
    #[arg(long, default_value_t = 20)]
    pub batches: usize,
    /// Largest accepted tilt of the input axis during the run, rad ([P2]: 1e-4).
    #[arg(long, default_value_t = 1e-4)]
    pub tilt_limit_rad: f64,
    /// Print the result as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(cmd: IdentifyCommand) -> anyhow::Result<()> {
    match cmd {
        IdentifyCommand::Positions(args) => run_positions(args),
        IdentifyCommand::Measure(args) => run_measure(args),
    }
}

fn load_passport(arg: &str) -> anyhow::Result<Passport> {
    vibro_config::resolve_passport(arg).with_context(|| format!("loading passport {arg:?}"))
}

// ---------------------------------------------------------------------------------
// CSV reading shared by both commands.

/// A CSV table: header names with the line of each data row.
struct Table {
    header: Vec<String>,
    header_line: usize,
    rows: Vec<(usize, csv::StringRecord)>,
}

/// Reads a CSV file whose blank lines and `#` comment lines are skipped.
///
/// The csv crate's line count skips some comment and blank lines between records, so
/// the file's own line numbers are kept here: comments and blanks are removed first,
/// and each record's line in the filtered text maps back to the file. A numeric table
/// has no quoted multi-line cells, so one record is one line. Rows whose number of
/// cells differs from the header are reported as problems, all at once.
fn read_table(file: &Path, problems: &mut Problems) -> anyhow::Result<Table> {
    let text = std::fs::read_to_string(file)
        .with_context(|| format!("{}: cannot read", file.display()))?;
    let mut file_lines = Vec::new();
    let mut kept = String::new();
    for (i, line) in text.lines().enumerate() {
        let trimmed = line.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            continue;
        }
        file_lines.push(i + 1);
        kept.push_str(line);
        kept.push('\n');
    }
    let line_of = |position: Option<&csv::Position>| {
        position
            .and_then(|p| usize::try_from(p.line()).ok())
            .and_then(|l| file_lines.get(l.wrapping_sub(1)).copied())
            .unwrap_or(0)
    };
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .flexible(true)
        .from_reader(kept.as_bytes());
    let header_record = reader
        .headers()
        .with_context(|| format!("{}: cannot read the header", file.display()))?
        .clone();
    let header: Vec<String> = header_record.iter().map(str::to_string).collect();
    let header_line = line_of(header_record.position());
    if header.iter().all(String::is_empty) {
        bail!("{}: empty file: a header row is required", file.display());
    }
    let mut rows = Vec::new();
    for record in reader.records() {
        let record = record.with_context(|| format!("{}: malformed CSV", file.display()))?;
        let line = line_of(record.position());
        if record.len() != header.len() {
            problems.push(format!(
                "line {line}: {} cells, the header (line {header_line}) has {}",
                record.len(),
                header.len()
            ));
            continue;
        }
        rows.push((line, record));
    }
    Ok(Table {
        header,
        header_line,
        rows,
    })
}

/// Collects every problem of a file, then fails once with all of them.
struct Problems {
    file: String,
    list: Vec<String>,
}

impl Problems {
    fn new(file: &Path) -> Self {
        Self {
            file: file.display().to_string(),
            list: Vec::new(),
        }
    }

    fn push(&mut self, problem: String) {
        self.list.push(problem);
    }

    fn finish(&self) -> anyhow::Result<()> {
        match self.list.len() {
            0 => Ok(()),
            1 => bail!("{}: {}", self.file, self.list[0]),
            n => bail!("{}: {n} problems:\n  {}", self.file, self.list.join("\n  ")),
        }
    }
}

/// Checks the header against the known columns; returns the index of each known one.
fn columns<const N: usize>(
    table: &Table,
    known: [&str; N],
    required: &[&str],
    problems: &mut Problems,
) -> [Option<usize>; N] {
    for name in &table.header {
        if !known.contains(&name.as_str()) {
            problems.push(format!(
                "header (line {}): unknown column {name:?} (known: {})",
                table.header_line,
                known.join(", ")
            ));
        }
    }
    let index = known.map(|k| table.header.iter().position(|h| h == k));
    for (k, i) in known.iter().zip(&index) {
        if i.is_none() && required.contains(k) {
            problems.push(format!(
                "header (line {}): missing column {k:?} (required: {})",
                table.header_line,
                required.join(", ")
            ));
        }
    }
    index
}

/// Parses one numeric cell; records a problem naming line, column, value and rule.
fn number(
    record: &csv::StringRecord,
    line: usize,
    column: &str,
    index: usize,
    rule: (&str, fn(f64) -> bool),
    problems: &mut Problems,
) -> Option<f64> {
    let cell = record.get(index).unwrap_or("");
    match cell.parse::<f64>() {
        Ok(v) if (rule.1)(v) => Some(v),
        _ => {
            problems.push(format!(
                "line {line}, column {column}: {cell:?}: {}",
                rule.0
            ));
            None
        }
    }
}

const FINITE: (&str, fn(f64) -> bool) = ("must be a finite number", |v| v.is_finite());
const AMPLITUDE: (&str, fn(f64) -> bool) = ("must be a finite vibration amplitude >= 0 g", |v| {
    v.is_finite() && v >= 0.0
});
const SIGMA: (&str, fn(f64) -> bool) = ("must be a finite standard uncertainty > 0 V", |v| {
    v.is_finite() && v > 0.0
});
const TP: (&str, fn(f64) -> bool) = ("must be a test-position number 1, 2, ...", |v| {
    v.is_finite() && v >= 1.0 && v.fract() == 0.0 && v <= f64::from(u32::MAX)
});

// ---------------------------------------------------------------------------------
// identify positions

/// Columns of the positions CSV, in this order in [`read_positions`].
const POSITION_COLUMNS: [&str; 8] = [
    "tp",
    "angle_deg",
    "aB3_g",
    "aB1_g",
    "aB2_g",
    "u_still_v",
    "u_vib_v",
    "u_sigma_v",
];

/// Reads the test positions and the CSV line of each.
fn read_positions(file: &Path) -> anyhow::Result<(Vec<TestPosition>, Vec<usize>)> {
    let mut problems = Problems::new(file);
    let table = read_table(file, &mut problems)?;
    let cols = columns(
        &table,
        POSITION_COLUMNS,
        &POSITION_COLUMNS[..7],
        &mut problems,
    );
    // Cells of the columns present are checked even when others are missing, so
    // that one run reports every problem.
    let mut positions = Vec::new();
    let mut lines = Vec::new();
    for (line, record) in &table.rows {
        let rules = [
            TP, FINITE, AMPLITUDE, AMPLITUDE, AMPLITUDE, FINITE, FINITE, SIGMA,
        ];
        let mut v = [0.0; 8];
        let mut ok = true;
        for (k, (rule, col)) in rules.iter().zip(&cols).enumerate() {
            if let Some(i) = col {
                match number(record, *line, POSITION_COLUMNS[k], *i, *rule, &mut problems) {
                    Some(x) => v[k] = x,
                    None => ok = false,
                }
            }
        }
        if !ok {
            continue;
        }
        let du_v = v[6] - v[5];
        positions.push(TestPosition {
            // Checked above: a whole number in 1..=u32::MAX.
            tp: v[0] as u32,
            angle_deg: v[1],
            amplitudes: Amplitudes {
                a_b3_g: v[2],
                a_b1_g: v[3],
                a_b2_g: v[4],
            },
            du_v,
            du_sigma_v: cols[7].map(|_| v[7]),
        });
        lines.push(*line);
    }
    if table.rows.is_empty() && problems.list.is_empty() {
        problems.push("no test positions: at least one data row is required".into());
    }
    problems.finish()?;
    Ok((positions, lines))
}

/// Where a library error points at a position by index, says which CSV line it is,
/// and translates the library's advice into command-line terms.
fn locate(e: &vibro_ident::Error, lines: &[usize]) -> String {
    use vibro_ident::Error as E;
    let index = match e {
        E::InvalidPosition { index, .. } => Some(*index),
        E::MixedAmplitudes { other_index, .. } => Some(*other_index),
        E::PartialUncertainties { first_missing, .. } => Some(*first_missing),
        _ => None,
    };
    let mut text = match index.and_then(|i| lines.get(i).map(|l| (i, l))) {
        Some((i, line)) => format!(" (position #{i} is on line {line})"),
        None => String::new(),
    };
    if matches!(e, E::MixedAmplitudes { .. }) {
        text += "; for positions at several amplitudes use --method coefficients";
    }
    text
}

/// One method's components and VE predictions.
#[derive(Debug, Serialize)]
struct MethodReport {
    estimate: ComponentsEstimate,
    predictions: Vec<VePrediction>,
}

impl MethodReport {
    fn new(estimate: ComponentsEstimate, at_g: &[f64]) -> Self {
        let predictions = at_g.iter().map(|a| estimate.predict(*a)).collect();
        Self {
            estimate,
            predictions,
        }
    }
}

#[derive(Debug, Serialize)]
struct CoefficientReport {
    terms: CoefficientEstimate,
    /// The components at the chosen amplitudes, and the VE predictions from them.
    components: MethodReport,
}

#[derive(Debug, Serialize)]
struct Skipped {
    method: &'static str,
    reason: String,
}

#[derive(Debug, Serialize)]
struct PositionsReport {
    file: String,
    passport: String,
    k1_v_per_g: f64,
    n_positions: usize,
    /// The passport's terms of section 5, `lambda = 1` (the test frequency is not in
    /// the CSV), for comparison.
    passport_terms: PassportTerms,
    closed_form: Option<MethodReport>,
    wls: Option<MethodReport>,
    coefficients: Option<CoefficientReport>,
    skipped: Vec<Skipped>,
}

/// The passport's section-5 terms with `lambda = 1`.
fn passport_terms(p: &Passport) -> PassportTerms {
    PassportTerms {
        c_asym: 0.637 * p.k1 * p.d1a,
        k2_per_g: p.k[2],
        k3_per_g2: p.k[3],
        k4_per_g3: p.k[4],
        k5_per_g4: p.k[5],
        m31_per_g: p.m31_per_g,
        m32_per_g: p.m32_per_g,
    }
}

fn run_positions(args: PositionsArgs) -> anyhow::Result<()> {
    // A flight acceleration's and a tone amplitude's rules (a scenario's, the
    // physics'), every bad value at once.
    let mut problems = crate::flags::FlagProblems::new();
    for a in &args.at_g {
        problems.accel_g("--at-g", *a);
    }
    for (name, value) in [
        ("--at-ab3-g", args.at_ab3_g),
        ("--at-ab1-g", args.at_ab1_g),
        ("--at-ab2-g", args.at_ab2_g),
    ] {
        if let Some(v) = value {
            problems.amplitude_g(name, v);
        }
    }
    problems.finish()?;
    let passport = load_passport(&args.passport)?;
    let k1 = passport.k1_v_per_g;
    let file = args.file.display().to_string();
    let (positions, lines) = read_positions(&args.file)?;
    let context = |method: &str, e: &vibro_ident::Error| {
        format!("{file}: {method}: {e}{}", locate(e, &lines))
    };
    let options = WlsOptions::default();
    let mut report = PositionsReport {
        file: file.clone(),
        passport: passport.id().to_string(),
        k1_v_per_g: k1,
        n_positions: positions.len(),
        passport_terms: passport_terms(&passport),
        closed_form: None,
        wls: None,
        coefficients: None,
        skipped: Vec::new(),
    };
    let want_cf = matches!(args.method, MethodArg::ClosedForm | MethodArg::Both);
    let want_wls = matches!(args.method, MethodArg::Wls | MethodArg::Both);
    let optional = args.method == MethodArg::Both;
    if want_cf {
        match vibro_ident::closed_form(&positions, k1) {
            Ok(e) => report.closed_form = Some(MethodReport::new(e, &args.at_g)),
            Err(e) if optional => report.skipped.push(Skipped {
                method: "closed_form",
                reason: context("closed form", &e),
            }),
            Err(e) => bail!(context("closed form", &e)),
        }
    }
    if want_wls {
        match vibro_ident::wls_components(&positions, k1, &options) {
            Ok(e) => report.wls = Some(MethodReport::new(e, &args.at_g)),
            Err(e) if optional => report.skipped.push(Skipped {
                method: "wls",
                reason: context("WLS", &e),
            }),
            Err(e) => bail!(context("WLS", &e)),
        }
    }
    if args.method == MethodArg::Coefficients {
        let terms = vibro_ident::wls_coefficients(&positions, k1, &options)
            .map_err(|e| anyhow::anyhow!(context("coefficient-level WLS", &e)))?;
        let a_b3_g = args
            .at_ab3_g
            .or_else(|| terms.a_b3_levels_g.last().copied())
            .unwrap_or(0.0);
        let amplitudes = Amplitudes {
            a_b3_g,
            a_b1_g: args.at_ab1_g.unwrap_or(a_b3_g),
            a_b2_g: args.at_ab2_g.unwrap_or(a_b3_g),
        };
        let components = MethodReport::new(terms.components_at(amplitudes), &args.at_g);
        report.coefficients = Some(CoefficientReport { terms, components });
    }
    if report.closed_form.is_none() && report.wls.is_none() && report.coefficients.is_none() {
        let reasons: Vec<String> = report.skipped.iter().map(|s| s.reason.clone()).collect();
        bail!("no method applies:\n  {}", reasons.join("\n  "));
    }
    if args.json {
        print_json(&report)
    } else {
        print_positions(&report)?;
        Ok(())
    }
}

/// A component in readable units: d0 in g with a prefix, delta(n) in ug/g^n.
fn fmt_component(i: usize, value: f64) -> String {
    match i {
        0..=2 => fmt_g(value),
        _ => format!("{:.4} ug/g{}", value * 1e6, ["", "^2", "^3"][i - 3]),
    }
}

const COMPONENT_LABELS: [&str; 6] = [
    "d0(1)", "d0(2)", "d0(3)", "delta(1)", "delta(2)", "delta(3)",
];

fn value_pm(value: String, sigma: Option<String>) -> String {
    match sigma {
        Some(s) => format!("{value} ± {s}"),
        None => format!("{value} ± unknown"),
    }
}

fn describe_basis(basis: &UncertaintyBasis) -> String {
    match basis {
        UncertaintyBasis::Given { chi2, dof } => {
            format!("from u_sigma_v (chi2 = {chi2:.3} for {dof} dof)")
        }
        UncertaintyBasis::ResidualScatter { dof, du_sigma_v } => format!(
            "from the residual scatter: sigma(dU) = {:.3} uV ({dof} dof)",
            du_sigma_v * 1e6
        ),
        UncertaintyBasis::Unknown { reason } => format!("unknown: {reason}"),
    }
}

fn print_positions(r: &PositionsReport) -> anyhow::Result<()> {
    outln!(
        "Identification from {} ({} positions), passport {} (K1 = {} V/g)",
        r.file,
        r.n_positions,
        r.passport,
        r.k1_v_per_g
    )?;
    let mut methods: Vec<(&str, &MethodReport)> = Vec::new();
    if let Some(m) = &r.closed_form {
        methods.push(("closed form (22)", m));
    }
    if let Some(m) = &r.wls {
        methods.push(("WLS", m));
    }
    if let Some(c) = &r.coefficients {
        methods.push(("from coefficient WLS", &c.components));
    }
    if let Some(first) = methods.first() {
        let a = first.1.estimate.amplitudes;
        outln!(
            "Components at aB3 = {} g (IA), aB1 = {} g (OA, for d0(2)), aB2 = {} g (PA, for d0(3))",
            a.a_b3_g,
            a.a_b1_g,
            a.a_b2_g
        )?;
        let passport = r.passport_terms.components_at(a).to_array();
        outln!()?;
        let mut header = format!("{:<10}", "component");
        for (name, _) in &methods {
            header += &format!("  {name:<30}");
        }
        outln!("{header}  passport (section 5, lambda = 1)")?;
        for (i, label) in COMPONENT_LABELS.iter().enumerate() {
            let mut row = format!("{label:<10}");
            for (_, m) in &methods {
                let e = &m.estimate;
                let value = fmt_component(i, e.components.to_array()[i]);
                let sigma = e.sigma.map(|s| fmt_component(i, s.to_array()[i]));
                row += &format!("  {:<30}", value_pm(value, sigma));
            }
            outln!("{row}  {}", fmt_component(i, passport[i]))?;
        }
        outln!()?;
        for (name, m) in &methods {
            outln!(
                "{name}: uncertainties {}",
                describe_basis(&m.estimate.basis)
            )?;
        }
        outln!()?;
        outln!("VE predicted by (23)")?;
        let mut header = format!("{:<10}", "aL");
        for (name, _) in &methods {
            header += &format!("  {name:<30}");
        }
        outln!("{}", header.trim_end())?;
        for (k, a_l_g) in first.1.predictions.iter().map(|p| p.a_l_g).enumerate() {
            let mut row = format!("{:<10}", format!("{a_l_g} g"));
            for (_, m) in &methods {
                let p = &m.predictions[k];
                row += &format!("  {:<30}", value_pm(fmt_g(p.ve_g), p.sigma_g.map(fmt_g)));
            }
            outln!("{}", row.trim_end())?;
        }
    }
    if let Some(c) = &r.coefficients {
        let t = &c.terms;
        outln!()?;
        outln!(
            "Passport terms (coefficient WLS over IA amplitudes {:?} g; {})",
            t.a_b3_levels_g,
            describe_basis(&t.basis)
        )?;
        let units = [
            "ppm", "ppm/g", "ppm/g^2", "ppm/g^3", "ppm/g^4", "ppm/g", "ppm/g",
        ];
        let labels = [
            "c_asym = 0.637*lambda*k1*d1A",
            "k2",
            "k3",
            "k4",
            "k5",
            "m31",
            "m32",
        ];
        let x = t.terms.to_array();
        let s = t.sigma.map(|s| s.to_array());
        let p = r.passport_terms.to_array();
        for i in 0..7 {
            let value = format!("{:.4} {}", x[i] * 1e6, units[i]);
            let sigma = s.map(|s| format!("{:.4} {}", s[i] * 1e6, units[i]));
            outln!(
                "  {:<30} {:<36} passport {:.4} {}",
                labels[i],
                value_pm(value, sigma),
                p[i] * 1e6,
                units[i]
            )?;
        }
    }
    for s in &r.skipped {
        outln!()?;
        outln!("{} skipped: {}", s.method, s.reason)?;
    }
    Ok(())
}

// ---------------------------------------------------------------------------------
// identify measure

/// Reads the three records of a section-8 measurement.
fn read_records(file: &Path) -> anyhow::Result<[Vec<f64>; 3]> {
    let mut problems = Problems::new(file);
    let table = read_table(file, &mut problems)?;
    let mut records: [Vec<f64>; 3] = Default::default();
    let has = |c: &str| table.header.iter().any(|h| h == c);
    if has("phase") || has("u_v") {
        let cols = columns(&table, ["phase", "u_v"], &["phase", "u_v"], &mut problems);
        if let [Some(phase_col), Some(u_col)] = cols {
            for (line, record) in &table.rows {
                let phase = record.get(phase_col).unwrap_or("");
                let slot = match phase {
                    "still1" => Some(0),
                    "vib" => Some(1),
                    "still2" => Some(2),
                    other => {
                        problems.push(format!(
                            "line {line}, column phase: {other:?}: must be still1, vib or still2"
                        ));
                        None
                    }
                };
                let value = number(record, *line, "u_v", u_col, FINITE, &mut problems);
                if let (Some(slot), Some(value)) = (slot, value) {
                    records[slot].push(value);
                }
            }
        }
    } else {
        let names = ["still1_v", "vib_v", "still2_v"];
        let cols = columns(&table, names, &names, &mut problems);
        for (line, record) in &table.rows {
            for (k, col) in cols.iter().enumerate() {
                let Some(i) = col else { continue };
                // An empty cell: that record has ended.
                if record.get(*i).unwrap_or("").is_empty() {
                    continue;
                }
                if let Some(v) = number(record, *line, names[k], *i, FINITE, &mut problems) {
                    records[k].push(v);
                }
            }
        }
    }
    problems.finish()?;
    Ok(records)
}

#[derive(Debug, Serialize)]
struct MeasureReport {
    file: String,
    passport: String,
    #[serde(flatten)]
    measurement: VeMeasurement,
}

fn run_measure(args: MeasureArgs) -> anyhow::Result<()> {
    let passport = load_passport(&args.passport)?;
    let file = args.file.display().to_string();
    let [u1, u2, u3] = read_records(&args.file)?;
    let options = MeasureOptions {
        n_batches: args.batches,
        tilt_limit_rad: args.tilt_limit_rad,
    };
    let measurement =
        vibro_ident::measure_ve_from_samples(&u1, &u2, &u3, passport.k1_v_per_g, &options)
            .with_context(|| format!("{file}: VE measurement (MODEL.md section 8)"))?;
    let report = MeasureReport {
        file,
        passport: passport.id().to_string(),
        measurement,
    };
    if args.json {
        return print_json(&report);
    }
    let m = &report.measurement;
    outln!(
        "VE measured from {} by [P2 (16)], passport {} (K1 = {} V/g)",
        report.file,
        report.passport,
        m.k1_v_per_g
    )?;
    outln!()?;
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
