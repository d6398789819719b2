//! `docs/messages.md` against the code: every type's section (type name, size, alignment,
//! and one table row per field with offset, size and C type) must equal what
//! `offset_of!`/`size_of`/`align_of` say. A field added, removed, moved or retyped in
//! either place fails this test; its message prints the section as the code sees it.

use std::collections::BTreeMap;
use vibro_msgs::{
    MessageKind, Stream, ACCEL_BLOCK_MAX, MAX_BANDS, MAX_TONES, SCHEMA_VERSION, UNITS,
    VIB_BLOCK_MAX,
};

fn doc() -> String {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/messages.md");
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("cannot read {path}: {e}"))
}

#[derive(Debug, PartialEq)]
struct Row {
    field: String,
    offset: usize,
    size: usize,
    c_type: String,
    unit: String,
    meaning: String,
}

#[derive(Debug, Default)]
struct Section {
    type_name: Option<String>,
    size: Option<usize>,
    align: Option<usize>,
    rows: Vec<Row>,
}

fn strip_ticks(s: &str) -> String {
    s.trim().trim_matches('`').to_string()
}

/// `### Name` sections, keyed by name, with their bullet facts and table rows.
fn sections(doc: &str) -> BTreeMap<String, Section> {
    let mut out: BTreeMap<String, Section> = BTreeMap::new();
    let mut current: Option<String> = None;
    for line in doc.lines() {
        if let Some(h) = line.strip_prefix("### ") {
            let name = h.trim().to_string();
            assert!(
                !out.contains_key(&name),
                "docs/messages.md has two sections named {name}"
            );
            out.insert(name.clone(), Section::default());
            current = Some(name);
            continue;
        }
        if line.starts_with("## ") || line.starts_with("# ") {
            current = None;
            continue;
        }
        let Some(section) = current.as_ref().and_then(|n| out.get_mut(n)) else {
            continue;
        };
        if let Some(v) = line.strip_prefix("- type name: ") {
            section.type_name = Some(strip_ticks(v));
        } else if let Some(v) = line.strip_prefix("- size: ") {
            // "- size: 824 bytes, alignment: 8 bytes"
            let (size, align) = v.split_once(", alignment: ").expect("size line format");
            section.size = Some(size.trim_end_matches(" bytes").trim().parse().unwrap());
            section.align = Some(align.trim_end_matches(" bytes").trim().parse().unwrap());
        } else if line.starts_with("| `") {
            let cells: Vec<&str> = line.trim().trim_matches('|').split('|').collect();
            assert_eq!(cells.len(), 6, "row needs 6 cells: {line}");
            section.rows.push(Row {
                field: strip_ticks(cells[0]),
                offset: cells[1].trim().parse().unwrap_or(usize::MAX),
                size: cells[2].trim().parse().unwrap_or(usize::MAX),
                c_type: strip_ticks(cells[3]),
                unit: cells[4].trim().to_string(),
                meaning: cells[5].trim().to_string(),
            });
        }
    }
    out
}

/// The section as the code sees it (units and meanings left for the writer).
fn expected_section(kind: MessageKind) -> String {
    let mut s = format!(
        "### {}\n\n- type name: `{}`\n- size: {} bytes, alignment: {} bytes\n\n\
         | field | offset | size | type | unit | meaning |\n|---|---:|---:|---|---|---|\n",
        kind.name(),
        kind.type_name(),
        kind.size_bytes(),
        kind.align_bytes()
    );
    for f in kind.fields() {
        s.push_str(&format!(
            "| `{}` | {} | {} | `{}` | ? | ? |\n",
            f.name,
            f.offset_bytes,
            f.size_bytes,
            f.c_type()
        ));
    }
    s
}

#[test]
fn every_type_section_matches_the_code_layout() {
    let doc = doc();
    let sections = sections(&doc);
    let mut problems = Vec::new();
    for kind in MessageKind::ALL {
        let Some(section) = sections.get(kind.name()) else {
            problems.push(format!(
                "no section for {kind}; expected:\n{}",
                expected_section(kind)
            ));
            continue;
        };
        let mut wrong = Vec::new();
        if section.type_name.as_deref() != Some(kind.type_name()) {
            wrong.push(format!("type name {:?}", section.type_name));
        }
        if section.size != Some(kind.size_bytes()) {
            wrong.push(format!("size {:?}", section.size));
        }
        if section.align != Some(kind.align_bytes()) {
            wrong.push(format!("alignment {:?}", section.align));
        }
        let fields = kind.fields();
        if section.rows.len() != fields.len() {
            wrong.push(format!(
                "{} rows for {} fields",
                section.rows.len(),
                fields.len()
            ));
        }
        for (i, f) in fields.iter().enumerate() {
            match section.rows.get(i) {
                Some(r)
                    if r.field == f.name
                        && r.offset == f.offset_bytes
                        && r.size == f.size_bytes
                        && r.c_type == f.c_type() =>
                {
                    if r.unit.is_empty()
                        || r.unit == "?"
                        || r.meaning.is_empty()
                        || r.meaning == "?"
                    {
                        wrong.push(format!("row `{}` lacks a unit or meaning", f.name));
                    }
                }
                other => wrong.push(format!(
                    "row {i}: doc {:?}, code `{}` at {} size {} `{}`",
                    other.map(|r| (&r.field, r.offset, r.size, &r.c_type)),
                    f.name,
                    f.offset_bytes,
                    f.size_bytes,
                    f.c_type()
                )),
            }
        }
        if !wrong.is_empty() {
            problems.push(format!(
                "{kind}: {}; the code's layout:\n{}",
                wrong.join("; "),
                expected_section(kind)
            ));
        }
    }
    assert!(
        problems.is_empty(),
        "docs/messages.md disagrees with the code:\n{}",
        problems.join("\n")
    );
}

#[test]
fn the_parser_notices_a_moved_or_missing_field() {
    // Guard the guard: a copy of the real document with one field removed and one offset
    // changed must not pass the comparison above.
    let doc = doc();
    let sections_ok = sections(&doc);
    let accel = &sections_ok["AccelBlock"];
    assert_eq!(accel.rows.len(), MessageKind::AccelBlock.fields().len());
    let moved = doc.replacen("| `t0_ns` | 16 |", "| `t0_ns` | 24 |", 1);
    assert_ne!(
        moved, doc,
        "the AccelBlock t0_ns row is where the test expects it"
    );
    let moved_rows = &sections(&moved)["AccelBlock"].rows;
    let t0 = moved_rows.iter().find(|r| r.field == "t0_ns").unwrap();
    assert_eq!(t0.offset, 24);
    let missing: String = doc
        .lines()
        .filter(|l| !l.starts_with("| `publish_ns` | 32 |"))
        .map(|l| format!("{l}\n"))
        .collect();
    assert_eq!(
        sections(&missing)["AccelBlock"].rows.len(),
        MessageKind::AccelBlock.fields().len() - 1
    );
}

#[test]
fn constants_and_service_names_are_documented() {
    let doc = doc();
    for (name, value) in [
        ("SCHEMA_VERSION", SCHEMA_VERSION as usize),
        ("UNITS", UNITS),
        ("ACCEL_BLOCK_MAX", ACCEL_BLOCK_MAX),
        ("VIB_BLOCK_MAX", VIB_BLOCK_MAX),
        ("MAX_TONES", MAX_TONES),
        ("MAX_BANDS", MAX_BANDS),
        ("LOG_TEXT_MAX", vibro_msgs::LOG_TEXT_MAX),
    ] {
        let row = format!("| `{name}` | {value} |");
        assert!(doc.contains(&row), "docs/messages.md lacks the row {row}");
    }
    let longest_prefix = vibro_msgs::MAX_SERVICE_NAME_LEN - vibro_msgs::max_suffix_len();
    let limit = format!("is at most {longest_prefix} bytes long");
    assert!(doc.contains(&limit), "docs/messages.md lacks \"{limit}\"");
    for stream in Stream::all() {
        let suffix = stream.suffix();
        let generic = match stream {
            Stream::Heartbeat(_) => "`{prefix}heartbeat/{service}`".to_string(),
            Stream::Progress(_) => "`{prefix}progress/{service}`".to_string(),
            Stream::Log(_) => "`{prefix}log/{service}`".to_string(),
            _ => format!("`{{prefix}}{suffix}`"),
        };
        assert!(doc.contains(&generic), "docs/messages.md lacks {generic}");
        if let Stream::Heartbeat(service) | Stream::Progress(service) | Stream::Log(service) =
            stream
        {
            assert!(
                doc.contains(&format!("`{service}`")),
                "docs/messages.md lacks the service `{service}`"
            );
        } else {
            let event = format!("`{{prefix}}{suffix}/event`");
            assert!(doc.contains(&event), "docs/messages.md lacks {event}");
        }
    }
}
