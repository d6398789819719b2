//! What a log carries beside its messages: every attachment and metadata record the
//! logs of vibrocomp hold, named, written and read here and nowhere else
//! (docs/logs.md, "Attachments and metadata").
//!
//! Writers collect them in a [`LogExtras`] (in the order they are to be written) and
//! write them with [`LogExtras::write_to`]; readers find the passports with
//! [`read_passports`].
//!
//! | name | media type | written by | holds |
//! |---|---|---|---|
//! | `passport-{i}-{id}.toml` | `application/toml` | `sim`, `record` | the passport of unit `i` (0..3), `id` its identifier |
//! | `scenario.toml` | `application/toml` | `sim` | the scenario as written |
//! | `estimator.toml`, `compensator.toml` | `application/toml` | `record` | the service's configuration |
//! | `accel-header.csv`, `vib-header.csv` | `text/csv` | `log import` | the CSV file's lines up to its header |
//! | the file's name | `application/octet-stream` | `record --attach FILE` | the file |
//!
//! | metadata record | written by | holds |
//! |---|---|---|
//! | `scenario` | `sim` | name, file, seed, rates, sensor, effects, duration, units |
//! | `effect-{i}` | `sim` | the parameters of the `i`-th effect switched on |
//! | `recording` | [`crate::record()`] | prefix, topics, the meaning of log time, start |
//! | `recorder` | `record` | program and process |
//! | `import` | [`crate::import::import`] | the import's options and what it found per stream |
//! | `attachments` | any writer whose attachments came from files | `{attachment name} = {where it came from}` |
//!
//! Attachment names hold no spaces, no parentheses and no path separators
//! ([`clean_name`]): where a file came from (`config/services/estimator.toml
//! (shipped)`) goes into the `attachments` metadata record instead. Logs written
//! before this naming carry `passport-{i}-{unit}.toml` (the simulator) and
//! `estimator.toml (config/services/estimator.toml)` (the recorder); [`read_passports`]
//! reads their passports too.

use std::collections::BTreeMap;
use std::path::Path;

use vibro_mcap::{Reader, Recorder};

use crate::{Error, Result};

/// Media type of TOML attachments (configurations, passports, scenarios).
pub const TOML: &str = "application/toml";
/// Media type of CSV attachments.
pub const CSV: &str = "text/csv";
/// Media type of attached files of unknown kind.
pub const OCTET_STREAM: &str = "application/octet-stream";

/// Attachment: the scenario a simulated flight ran, as written.
pub const SCENARIO_ATTACHMENT: &str = "scenario.toml";
/// Metadata record: the simulator's scenario.
pub const SCENARIO_METADATA: &str = "scenario";
/// Metadata record: the recorder's own (prefix, topics, log time).
pub const RECORDING_METADATA: &str = "recording";
/// Metadata record: the program that recorded.
pub const RECORDER_METADATA: &str = "recorder";
/// Metadata record: a CSV import.
pub const IMPORT_METADATA: &str = "import";
/// Metadata record of a log imported with a rig file (`log import --rig`): the rig, its
/// reference and its sensor chain.
pub const RIG_METADATA: &str = "rig";
/// Metadata record: where each attachment that came from a file came from.
pub const SOURCES_METADATA: &str = "attachments";

/// Units of a triad: passports are read for units `0..TRIAD_UNITS`.
pub const TRIAD_UNITS: usize = 3;

/// `raw` as an attachment name: every character that is not a letter, a digit, `.`,
/// `-`, `_` or `+` (spaces, parentheses, path separators, quotes) becomes `_`; an
/// empty name becomes `_`.
pub fn clean_name(raw: &str) -> String {
    let name: String = raw
        .chars()
        .map(|c| {
            if c.is_alphanumeric() || matches!(c, '.' | '-' | '_' | '+') {
                c
            } else {
                '_'
            }
        })
        .collect();
    if name.is_empty() {
        "_".to_string()
    } else {
        name
    }
}

/// `passport-{index}-{id}.toml`: the passport of unit `index` of the triad.
pub fn passport_name(index: usize, id: &str) -> String {
    format!("passport-{index}-{}.toml", clean_name(id))
}

/// `{service}.toml`: a service's configuration.
pub fn service_config_name(service: &str) -> String {
    format!("{}.toml", clean_name(service))
}

/// `{stream}-header.csv`: the lines of an imported CSV file up to its header.
pub fn csv_header_name(stream: &str) -> String {
    format!("{}-header.csv", clean_name(stream))
}

/// `effect-{index}`: the metadata record of the `index`-th effect switched on.
pub fn effect_metadata_name(index: usize) -> String {
    format!("effect-{index}")
}

/// The unit index of a passport attachment, `passport-{i}-...` with `i` below
/// [`TRIAD_UNITS`]: this naming and the ones before it (`passport-{i}-{unit}.toml`,
/// `passport-{i}-{id}.toml`) alike.
pub fn passport_index(name: &str) -> Option<usize> {
    name.strip_prefix("passport-")?
        .split('-')
        .next()?
        .parse::<usize>()
        .ok()
        .filter(|&i| i < TRIAD_UNITS)
}

/// One attachment to write.
#[derive(Debug, Clone, PartialEq)]
pub struct Attachment {
    pub name: String,
    pub media_type: String,
    pub data: Vec<u8>,
    /// Where it came from (a path, `... (shipped)`), for the `attachments` metadata
    /// record; `None` for what the writer made itself.
    pub source: Option<String>,
}

#[derive(Debug, Clone, PartialEq)]
enum Item {
    Attachment(Attachment),
    Metadata(String, BTreeMap<String, String>),
}

/// The attachments and metadata records of a log, in the order they are written.
#[derive(Debug, Clone, PartialEq)]
pub struct LogExtras {
    items: Vec<Item>,
    /// Log and creation time of the attachments, ns; `None`: the recorder's clock.
    time_ns: Option<u64>,
}

impl LogExtras {
    /// For a generated log (simulated, imported): attachments at time 0, so that the log
    /// is a function of its inputs, bit-identical from run to run.
    pub fn generated() -> Self {
        Self {
            items: Vec::new(),
            time_ns: Some(0),
        }
    }

    /// For a recording: attachments stamped with the wall clock when written.
    pub fn recorded() -> Self {
        Self {
            items: Vec::new(),
            time_ns: None,
        }
    }

    /// Nothing to write.
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// The attachments so far, in order.
    pub fn attachments(&self) -> impl Iterator<Item = &Attachment> {
        self.items.iter().filter_map(|i| match i {
            Item::Attachment(a) => Some(a),
            Item::Metadata(..) => None,
        })
    }

    fn attach(&mut self, name: String, media_type: &str, data: Vec<u8>, source: Option<String>) {
        self.items.push(Item::Attachment(Attachment {
            name,
            media_type: media_type.to_string(),
            data,
            source,
        }));
    }

    /// The passport of unit `index` (its TOML text), named by its identifier `id`
    /// ([`passport_name`]).
    pub fn passport(&mut self, index: usize, id: &str, toml: String) {
        self.attach(passport_name(index, id), TOML, toml.into_bytes(), None);
    }

    /// A service's configuration (`estimator`, `compensator`) and where it came from
    /// ([`service_config_name`]).
    pub fn service_config(&mut self, service: &str, source: &str, text: Vec<u8>) {
        self.attach(
            service_config_name(service),
            TOML,
            text,
            Some(source.to_string()),
        );
    }

    /// The scenario as written ([`SCENARIO_ATTACHMENT`]).
    pub fn scenario_text(&mut self, text: Vec<u8>) {
        self.attach(SCENARIO_ATTACHMENT.to_string(), TOML, text, None);
    }

    /// An imported CSV file's lines up to its header ([`csv_header_name`]).
    pub fn csv_header(&mut self, stream: &str, preamble: String) {
        self.attach(csv_header_name(stream), CSV, preamble.into_bytes(), None);
    }

    /// A file given by the user, named by its file name ([`clean_name`]), its path
    /// kept as its source.
    pub fn file(&mut self, path: &Path, data: Vec<u8>) {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().to_string())
            .unwrap_or_else(|| path.display().to_string());
        self.attach(
            clean_name(&name),
            OCTET_STREAM,
            data,
            Some(path.display().to_string()),
        );
    }

    /// A metadata record (names: the `*_METADATA` constants, [`effect_metadata_name`]).
    pub fn metadata(&mut self, name: &str, entries: BTreeMap<String, String>) {
        self.items.push(Item::Metadata(name.to_string(), entries));
    }

    /// Writes every record in order, then the [`SOURCES_METADATA`] record if any
    /// attachment came from a file. Waits for room in the recorder's queue.
    pub fn write_to(&self, recorder: &Recorder) -> Result<()> {
        for item in &self.items {
            match (item, self.time_ns) {
                (Item::Attachment(a), Some(t)) => {
                    recorder.add_attachment_at(&a.name, &a.media_type, a.data.clone(), t)?
                }
                (Item::Attachment(a), None) => {
                    recorder.add_attachment(&a.name, &a.media_type, a.data.clone())?
                }
                (Item::Metadata(name, entries), _) => {
                    recorder.add_metadata(name, entries.clone())?
                }
            }
        }
        let sources: BTreeMap<String, String> = self
            .attachments()
            .filter_map(|a| Some((a.name.clone(), a.source.clone()?)))
            .collect();
        if !sources.is_empty() {
            recorder.add_metadata(SOURCES_METADATA, sources)?;
        }
        Ok(())
    }
}

/// A passport a log carries: its unit, its attachment and its TOML text.
#[derive(Debug, Clone, PartialEq)]
pub struct LogPassport {
    /// The unit, `0..TRIAD_UNITS`.
    pub index: usize,
    /// The attachment's name.
    pub attachment: String,
    /// The passport as TOML (`vibro_config::parse_passport` reads it).
    pub toml: String,
}

/// The passports a log carries, in file order (a later one of the same unit follows an
/// earlier one: the caller keeps the last): every attachment named `passport-{i}-...`
/// with `i` below [`TRIAD_UNITS`], in this naming or the ones before it
/// ([`passport_index`]).
pub fn read_passports(reader: &mut Reader) -> Result<Vec<LogPassport>> {
    let mut out = Vec::new();
    for name in reader.attachment_names() {
        let Some(index) = passport_index(&name) else {
            continue;
        };
        let Some(bytes) = reader.read_attachment(&name)? else {
            continue;
        };
        let toml = String::from_utf8(bytes).map_err(|source| Error::AttachmentText {
            name: name.clone(),
            source,
        })?;
        out.push(LogPassport {
            index,
            attachment: name,
            toml,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_hold_no_spaces_parentheses_or_separators() {
        assert_eq!(passport_name(0, "AL-15"), "passport-0-AL-15.toml");
        assert_eq!(
            passport_name(2, "my unit (b)"),
            "passport-2-my_unit__b_.toml"
        );
        assert_eq!(service_config_name("estimator"), "estimator.toml");
        assert_eq!(csv_header_name("vib"), "vib-header.csv");
        assert_eq!(clean_name("a/b\\c d\"e'f"), "a_b_c_d_e_f");
        assert_eq!(clean_name(""), "_");
        assert_eq!(clean_name("АК1.toml"), "АК1.toml");
    }

    /// This naming and the two before it give the unit; other names give none.
    #[test]
    fn passports_of_every_naming_are_found() {
        for (name, index) in [
            ("passport-0-AL-15.toml", Some(0)),
            ("passport-1-AK2.toml", Some(1)),
            ("passport-2-AL-1M.toml", Some(2)),
            ("passport-3-AL-15.toml", None),
            ("passport-x-AL-15.toml", None),
            ("passports.toml", None),
            ("estimator.toml", None),
        ] {
            assert_eq!(passport_index(name), index, "{name}");
        }
    }

    /// Written, then read back: names, order, media types, times and the record of
    /// sources.
    #[test]
    fn extras_are_written_in_order_and_passports_read_back() {
        let dir = std::env::temp_dir().join(format!("vibro-log-extras-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("x.mcap");
        let rec = Recorder::create(&path, vibro_mcap::RecorderOptions::default()).unwrap();
        let mut extras = LogExtras::generated();
        extras.passport(0, "AL-15", "id = \"AL-15\"\n".into());
        extras.metadata(
            SCENARIO_METADATA,
            BTreeMap::from([("seed".into(), "1".into())]),
        );
        extras.service_config(
            "estimator",
            "config/services/estimator.toml (shipped)",
            b"a = 1\n".to_vec(),
        );
        extras.passport(1, "AL-15", "id = \"AL-15\"\nk1 = 1\n".into());
        // A passport of the previous naming.
        extras.attach(
            "passport-2-AK3.toml".into(),
            TOML,
            b"id = \"AK\"\n".to_vec(),
            None,
        );
        extras.write_to(&rec).unwrap();
        rec.finish().unwrap();

        let info = vibro_mcap::info(&path).unwrap();
        let names: Vec<&str> = info.attachments.iter().map(|a| a.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "passport-0-AL-15.toml",
                "estimator.toml",
                "passport-1-AL-15.toml",
                "passport-2-AK3.toml"
            ]
        );
        assert!(info.attachments.iter().all(|a| a.log_time_ns == 0));
        let meta: Vec<&str> = info.metadata.iter().map(|m| m.name.as_str()).collect();
        assert_eq!(meta, [SCENARIO_METADATA, SOURCES_METADATA]);
        assert_eq!(
            info.metadata[1].entries["estimator.toml"],
            "config/services/estimator.toml (shipped)"
        );

        let mut reader = Reader::open(&path).unwrap();
        let passports = read_passports(&mut reader).unwrap();
        let got: Vec<(usize, &str)> = passports
            .iter()
            .map(|p| (p.index, p.attachment.as_str()))
            .collect();
        assert_eq!(
            got,
            [
                (0, "passport-0-AL-15.toml"),
                (1, "passport-1-AL-15.toml"),
                (2, "passport-2-AK3.toml")
            ]
        );
        assert_eq!(passports[1].toml, "id = \"AL-15\"\nk1 = 1\n");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
