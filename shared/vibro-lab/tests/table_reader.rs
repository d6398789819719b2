//! The lab's table reader (`CampaignTable::read`, `vibro_lab::table_input`) under a
//! deterministic randomized property test ("Reliability, round four": a fuzz or
//! property target for the table reader). Tables are drawn with a seeded ChaCha
//! generator: the required columns in any order and up to 50 extras, up to 200 rows,
//! cells padded, quoted or empty, blank and comment lines anywhere, every line ending
//! (`\n`, `\r\n`, a lone `\r`, the last line with or without one), a UTF-8 byte order
//! mark; then one damage of: Latin-1 bytes, UTF-16 (with and without its byte order
//! mark), a NUL byte, a line over the cap, a cell too many, a quote left open, random
//! bytes overwritten. Properties:
//!
//! - never a panic;
//! - a table that is valid is read whole: every row, its run id and its own line number
//!   (comment and blank lines counted, whatever the line ending);
//! - each damage is refused with the message the reader gives for it, naming the file,
//!   the line and the column where it has them;
//! - every refusal is short: the file named first, at most 20 problems listed and a
//!   count of the rest, each problem under 1 KiB (hostile input is quoted by its
//!   excerpt);
//! - memory is bounded: no more of the input is read than up to the end of the line
//!   that is over the cap, plus one buffer (64 KiB).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::io::Read;
use std::path::Path;
use vibro_lab::table_input::{MAX_COLUMNS, MAX_LINE_BYTES};
use vibro_lab::{BaseMode, CampaignTable, LabModel, REQUIRED_COLUMNS};

/// Cases drawn (each a table of up to 200 rows): about a second in a debug build.
const CASES: u64 = 600;

/// The reader's buffer, bytes (`table_input`'s).
const BUFFER_BYTES: usize = 1 << 16;

/// A reader that counts the bytes taken from it.
struct Counting<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Read for Counting<'_> {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        let n = out.len().min(self.bytes.len() - self.at);
        out[..n].copy_from_slice(&self.bytes[self.at..self.at + n]);
        self.at += n;
        Ok(n)
    }
}

/// What the reader must make of a case.
#[derive(Debug)]
enum Expect {
    /// Every row read, with these run ids and lines.
    Rows(Vec<(String, usize)>),
    /// Refused with a message holding every one of these.
    Refused(Vec<String>),
    /// Anything but a panic (random bytes overwritten).
    Any,
}

/// One line of the table as written: its text and, for a data row, its run id.
struct Line {
    text: Vec<u8>,
    run_id: Option<String>,
}

fn valid_cell(column: &str, row: usize, rng: &mut ChaCha8Rng) -> String {
    match column {
        "run_id" => format!("R{row}"),
        "passport" => "AL-15".into(),
        "aL1_g" | "aL2_g" | "aB1_g" | "aB2_g" => "0".into(),
        "aL3_g" => ["1", "-1", "0.5"][rng.random_range(0..3)].into(),
        "freq_hz" => format!("{}", rng.random_range(10..200)),
        "aB3_g" => format!("{:.3}", rng.random_range(0.1..2.0)),
        "ve_measured_g" => format!("{:e}", rng.random_range(1e-6..1e-4)),
        "ve_uncertainty_g" => "1e-7".into(),
        c if c.starts_with('x') => {
            if rng.random_bool(0.3) {
                String::new()
            } else {
                format!("{}", rng.random_range(-1e3..1e3))
            }
        }
        // The phases and the random part: empty (a tone only).
        _ => String::new(),
    }
}

/// A cell as written: padded with blanks, or quoted, now and then.
fn written(cell: &str, rng: &mut ChaCha8Rng) -> String {
    match rng.random_range(0..10) {
        0 => format!("  {cell} "),
        1 => format!("\"{cell}\""),
        _ => cell.to_string(),
    }
}

/// Comment and blank lines, now and then.
fn noise(lines: &mut Vec<Line>, rng: &mut ChaCha8Rng) {
    while rng.random_bool(0.15) {
        let text = if rng.random_bool(0.5) {
            b"# a comment, \"with a quote".to_vec()
        } else {
            b"   ".to_vec()
        };
        lines.push(Line { text, run_id: None });
    }
}

/// Draws case `seed`: its bytes and what the reader must make of them.
fn draw(seed: u64) -> (Vec<u8>, Expect) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut columns: Vec<String> = REQUIRED_COLUMNS.iter().map(|c| c.to_string()).collect();
    // The required columns in another order, now and then.
    if rng.random_bool(0.3) {
        for i in (1..columns.len()).rev() {
            columns.swap(i, rng.random_range(0..=i));
        }
    }
    let extras = match rng.random_range(0..10) {
        0 => rng.random_range(0..=50),
        1..=3 => rng.random_range(1..5),
        _ => 0,
    };
    columns.extend((0..extras).map(|j| format!("x{j}")));
    let rows = match rng.random_range(0..20) {
        0 => 0,
        1 => 200,
        _ => rng.random_range(1..30),
    };
    let mut lines: Vec<Line> = Vec::new();
    noise(&mut lines, &mut rng);
    let header: Vec<String> = columns.iter().map(|c| written(c, &mut rng)).collect();
    lines.push(Line {
        text: header.join(",").into_bytes(),
        run_id: None,
    });
    for r in 0..rows {
        noise(&mut lines, &mut rng);
        let cells: Vec<String> = columns
            .iter()
            .map(|c| {
                let v = valid_cell(c, r, &mut rng);
                written(&v, &mut rng)
            })
            .collect();
        lines.push(Line {
            text: cells.join(",").into_bytes(),
            run_id: Some(format!("R{r}")),
        });
    }
    noise(&mut lines, &mut rng);
    let header_line = lines
        .iter()
        .position(|l| {
            l.run_id.is_none()
                && !l.text.starts_with(b"#")
                && !l.text.iter().all(u8::is_ascii_whitespace)
        })
        .unwrap_or(0)
        + 1;
    let data: Vec<usize> = (0..lines.len())
        .filter(|&i| lines[i].run_id.is_some())
        .collect();
    let col = |name: &str| columns.iter().position(|c| c == name).unwrap_or(0);

    // The damage, if any, and what it must give.
    let mut expect = if columns.len() > MAX_COLUMNS {
        Expect::Refused(vec![format!(
            "p.csv: line {header_line} (header): {} columns: at most {MAX_COLUMNS}",
            columns.len()
        )])
    } else if rows == 0 {
        Expect::Refused(vec!["p.csv: no condition rows".into()])
    } else {
        Expect::Rows(
            data.iter()
                .map(|&i| (lines[i].run_id.clone().unwrap_or_default(), i + 1))
                .collect(),
        )
    };
    let mut utf16 = None;
    let valid = matches!(expect, Expect::Rows(_));
    if valid {
        let at = data[rng.random_range(0..data.len())];
        let line = at + 1;
        let cells: Vec<Vec<u8>> = lines[at]
            .text
            .split(|&b| b == b',')
            .map(<[u8]>::to_vec)
            .collect();
        let set = |j: usize, cell: &[u8], lines: &mut Vec<Line>| {
            let mut c = cells.clone();
            c[j] = cell.to_vec();
            lines[at].text = c.join(&b","[..]);
        };
        match rng.random_range(0..12) {
            0 => {
                // Latin-1: "Résumé" as ISO 8859-1.
                set(col("run_id"), b"R\xe9sum\xe9", &mut lines);
                expect = Expect::Refused(vec![format!(
                    "line {line}, column {} = \"R\\xe9sum\\xe9\": not UTF-8 (byte 0xe9 at 1)",
                    col("run_id") + 1
                )]);
            }
            1 => {
                utf16 = Some(rng.random_bool(0.5));
                expect = Expect::Refused(vec!["p.csv: UTF-16 text (byte order mark".into()]);
            }
            2 => {
                set(col("ve_measured_g"), b"1e-5\0", &mut lines);
                expect = Expect::Refused(vec![format!(
                    "line {line}, column ve_measured_g = \"1e-5\\u{{0}}\": must be a finite number"
                )]);
            }
            3 => {
                let long = vec![b'7'; MAX_LINE_BYTES + rng.random_range(1..100_000)];
                set(col("aL3_g"), &long, &mut lines);
                expect = Expect::Refused(vec![format!(
                    "p.csv: line {line}: longer than {MAX_LINE_BYTES} bytes"
                )]);
            }
            4 => {
                lines[at].text.extend_from_slice(b",1");
                expect = Expect::Refused(vec![format!(
                    "line {line}: {} cells where the header has {}",
                    columns.len() + 1,
                    columns.len()
                )]);
            }
            5 => {
                // In the last cell: no quote after it can close it.
                set(columns.len() - 1, b"\"open, on", &mut lines);
                expect = Expect::Refused(vec![format!(
                    "line {line}: a quoted cell is not closed on its line"
                )]);
            }
            6 => expect = Expect::Any,
            _ => {}
        }
    }
    let eol: &[u8] = [&b"\n"[..], b"\r\n", b"\r"][rng.random_range(0..3)];
    let mut bytes = Vec::new();
    if rng.random_bool(0.2) {
        bytes.extend_from_slice(b"\xef\xbb\xbf");
    }
    for (i, l) in lines.iter().enumerate() {
        bytes.extend_from_slice(&l.text);
        if i + 1 < lines.len() || rng.random_bool(0.7) {
            bytes.extend_from_slice(eol);
        }
    }
    if let Some(with_mark) = utf16 {
        let text = String::from_utf8_lossy(&bytes).into_owned();
        // Its own mark only (a UTF-8 one would become U+FEFF, UTF-16's mark).
        let text = text.trim_start_matches('\u{feff}');
        let mut out = if with_mark {
            vec![0xff, 0xfe]
        } else {
            Vec::new()
        };
        out.extend(text.encode_utf16().flat_map(u16::to_le_bytes));
        bytes = out;
        if !with_mark {
            expect = Expect::Refused(vec!["NUL bytes".into()]);
        }
    }
    if matches!(expect, Expect::Any) {
        for _ in 0..rng.random_range(1..20) {
            let i = rng.random_range(0..bytes.len());
            bytes[i] = rng.random();
        }
    }
    (bytes, expect)
}

/// The end of the line holding byte offset `at` (its line ending excluded).
fn line_end(bytes: &[u8], at: usize) -> usize {
    bytes[at..]
        .iter()
        .position(|&b| b == b'\n' || b == b'\r')
        .map_or(bytes.len(), |k| at + k)
}

#[test]
fn every_table_drawn_is_read_or_refused_clearly_within_bounds() {
    let model = LabModel::base(BaseMode::Exact);
    let mut counts = [0usize; 3];
    for seed in 0..CASES {
        let (bytes, expect) = draw(seed);
        let mut input = Counting {
            bytes: &bytes,
            at: 0,
        };
        let got = CampaignTable::read(&mut input, Path::new("p.csv"), Path::new("."), &model);
        // Memory: the reader stops within one buffer of the first line over the cap.
        let long = bytes
            .split(|&b| b == b'\n' || b == b'\r')
            .scan(0usize, |start, l| {
                let s = *start;
                *start += l.len() + 1;
                Some((s, l.len()))
            })
            .find(|&(_, len)| len > MAX_LINE_BYTES);
        if let Some((start, _)) = long {
            // The cap, and a buffer read ahead (and a byte order mark's 3 bytes).
            let bound = start + MAX_LINE_BYTES + 2 * BUFFER_BYTES + 3;
            assert!(
                input.at <= bound,
                "seed {seed}: read {} bytes of {}, the long line spans {start}..{}",
                input.at,
                bytes.len(),
                line_end(&bytes, start)
            );
        }
        match (&expect, got) {
            (Expect::Rows(rows), Ok(t)) => {
                counts[0] += 1;
                let read: Vec<(String, usize)> = t
                    .conditions
                    .iter()
                    .map(|c| (c.run_id.clone(), c.line))
                    .collect();
                assert_eq!(&read, rows, "seed {seed}");
            }
            (Expect::Rows(_), Err(e)) => panic!("seed {seed}: a valid table refused: {e}"),
            (Expect::Refused(parts), Ok(_)) => {
                panic!("seed {seed}: accepted, expected a refusal with {parts:?}")
            }
            (_, Ok(_)) => counts[2] += 1,
            (expect, Err(e)) => {
                let e = e.to_string();
                assert!(e.starts_with("p.csv: "), "seed {seed}: {e}");
                let problems: Vec<&str> = e.split("\n  ").collect();
                assert!(
                    problems.len() <= 21,
                    "seed {seed}: {} problems listed",
                    problems.len()
                );
                for p in &problems {
                    assert!(
                        p.len() < 1024,
                        "seed {seed}: a problem of {} bytes: {p}",
                        p.len()
                    );
                }
                if let Expect::Refused(parts) = expect {
                    counts[1] += 1;
                    for part in parts {
                        assert!(e.contains(part.as_str()), "seed {seed}: no {part:?} in {e}");
                    }
                } else {
                    counts[2] += 1;
                }
            }
        }
    }
    // The draw covers each outcome.
    assert!(
        counts.iter().all(|&n| n >= 20),
        "read, refused, random: {counts:?}"
    );
}

#[test]
fn an_endless_input_is_read_no_further_than_the_cap_and_a_buffer() {
    struct Endless(u64, u8);
    impl Read for Endless {
        fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
            out.fill(self.1);
            self.0 += out.len() as u64;
            Ok(out.len())
        }
    }
    let model = LabModel::base(BaseMode::Exact);
    // `/dev/zero`, and a line of commas (a million columns and more).
    for byte in [0u8, b','] {
        let mut input = Endless(0, byte);
        let e = CampaignTable::read(&mut input, Path::new("/dev/zero"), Path::new("."), &model)
            .expect_err("no table")
            .to_string();
        assert!(
            e.starts_with("/dev/zero: line 1: longer than 65536 bytes"),
            "{e}"
        );
        assert!(e.len() < 1024, "{e}");
        assert!(
            input.0 <= (MAX_LINE_BYTES + BUFFER_BYTES) as u64 + 3,
            "{} bytes read",
            input.0
        );
    }
}
