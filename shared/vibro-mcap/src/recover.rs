//! Rewriting a damaged recording (a crash: no summary, no footer, perhaps half a chunk)
//! into a valid file holding everything up to its last complete chunk.
//!
//! The damaged file is read record by record with chunks kept whole. A chunk is copied
//! only if it is complete and its CRC checks out: its schemas, channels and messages are
//! then written to the new file (same IDs, same bytes, new chunks). Attachments and
//! metadata outside chunks are copied too. Reading stops at the first record that ends
//! past the end of the file, at a record that cannot be parsed, or at the data-end record
//! of a complete file. A chunk that is complete but corrupt (CRC or decompression error)
//! is skipped and counted, and reading goes on: the records after it are still framed.

use crate::{guard, Error, Result};
use mcap::records::Record as McapRecord;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// What [`recover`] found and wrote.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct RecoverReport {
    pub input: PathBuf,
    pub output: PathBuf,
    /// Size of the damaged file.
    pub input_bytes: u64,
    /// Bytes of the damaged file up to the end of the last record read whole.
    pub valid_prefix_bytes: u64,
    /// The input reached its data-end record: it was not damaged at the end.
    pub input_complete: bool,
    /// Why reading stopped early, if it did.
    pub stop_reason: Option<String>,
    /// Chunks copied.
    pub chunks_recovered: u64,
    /// Complete chunks skipped because their CRC or compression was broken.
    pub chunks_skipped: u64,
    /// Messages copied, in total and per topic.
    pub messages_recovered: u64,
    pub messages_per_topic: BTreeMap<String, u64>,
    /// Messages dropped because their channel was defined only in a skipped chunk.
    pub messages_orphaned: u64,
    pub attachments: u64,
    pub metadata: u64,
    /// Size of the recovered file.
    pub output_bytes: u64,
}

struct Copier<W: Write + Seek> {
    out_path: PathBuf,
    writer: mcap::Writer<W>,
    schemas: HashMap<u16, u16>,
    channels: HashMap<u16, String>,
    report: RecoverReport,
}

impl<W: Write + Seek> Copier<W> {
    fn new(
        input: &Path,
        input_bytes: u64,
        out_path: &Path,
        out: W,
        profile: String,
    ) -> Result<Copier<W>> {
        let writer = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .compression_threads(0)
            .profile(profile)
            .create(out)
            .map_err(|e| Error::mcap(out_path, e))?;
        Ok(Copier {
            out_path: out_path.to_path_buf(),
            writer,
            schemas: HashMap::new(),
            channels: HashMap::new(),
            report: RecoverReport {
                input: input.to_path_buf(),
                output: out_path.to_path_buf(),
                input_bytes,
                valid_prefix_bytes: 0,
                input_complete: false,
                stop_reason: None,
                chunks_recovered: 0,
                chunks_skipped: 0,
                messages_recovered: 0,
                messages_per_topic: BTreeMap::new(),
                messages_orphaned: 0,
                attachments: 0,
                metadata: 0,
                output_bytes: 0,
            },
        })
    }

    fn mcap(&self, e: mcap::McapError) -> Error {
        Error::mcap(&self.out_path, e)
    }

    /// Copies one record of the data section (or of a chunk). Returns false at data end.
    fn copy(&mut self, record: McapRecord<'_>) -> Result<bool> {
        match record {
            McapRecord::Schema { header, data } => {
                let id = self
                    .writer
                    .add_schema_with_id(header.id, &header.name, &header.encoding, &data)
                    .map_err(|e| self.mcap(e))?;
                self.schemas.insert(header.id, id);
            }
            McapRecord::Channel(c) => {
                if c.schema_id != 0 && !self.schemas.contains_key(&c.schema_id) {
                    return Ok(true);
                }
                self.writer
                    .add_channel_with_id(
                        c.id,
                        c.schema_id,
                        &c.topic,
                        &c.message_encoding,
                        &c.metadata,
                    )
                    .map_err(|e| self.mcap(e))?;
                self.channels.insert(c.id, c.topic);
            }
            McapRecord::Message { header, data } => {
                let Some(topic) = self.channels.get(&header.channel_id) else {
                    self.report.messages_orphaned += 1;
                    return Ok(true);
                };
                *self
                    .report
                    .messages_per_topic
                    .entry(topic.clone())
                    .or_insert(0) += 1;
                self.report.messages_recovered += 1;
                self.writer
                    .write_to_known_channel(&header, &data)
                    .map_err(|e| self.mcap(e))?;
            }
            McapRecord::Attachment { header, data, .. } => {
                self.writer
                    .attach(&mcap::Attachment {
                        log_time: header.log_time,
                        create_time: header.create_time,
                        name: header.name,
                        media_type: header.media_type,
                        data: Cow::Borrowed(&data),
                    })
                    .map_err(|e| self.mcap(e))?;
                self.report.attachments += 1;
            }
            McapRecord::Metadata(m) => {
                self.writer.write_metadata(&m).map_err(|e| self.mcap(e))?;
                self.report.metadata += 1;
            }
            McapRecord::DataEnd(_) => return Ok(false),
            _ => {}
        }
        Ok(true)
    }

    /// Copies a whole chunk if it decompresses, its CRC checks out and its records
    /// parse (cut into records by `guard::chunk`, not by mcap).
    fn copy_chunk(&mut self, header: mcap::records::ChunkHeader, data: &[u8]) -> Result<()> {
        let mut buf = Vec::new();
        let records = guard::chunk(&header, data, &mut buf)
            .ok()
            .and_then(|records| {
                records
                    .into_iter()
                    .map(|(opcode, body)| mcap::parse_record(opcode, body).ok())
                    .collect::<Option<Vec<_>>>()
            });
        match records {
            Some(records) => {
                for record in records {
                    self.copy(record)?;
                }
                self.report.chunks_recovered += 1;
            }
            None => self.report.chunks_skipped += 1,
        }
        Ok(())
    }
}

/// Recovers `damaged` into a new file `out` (created or truncated; zstd chunks).
pub fn recover(damaged: impl AsRef<Path>, out: impl AsRef<Path>) -> Result<RecoverReport> {
    let input = damaged.as_ref();
    let out_path = out.as_ref();
    let file = File::open(input).map_err(|e| Error::io("open", input, e))?;
    let input_bytes = file
        .metadata()
        .map_err(|e| Error::io("stat", input, e))?
        .len();
    let out_file = File::create(out_path).map_err(|e| Error::io("create", out_path, e))?;
    let (report, out) =
        recover_from_reader(file, input, input_bytes, BufWriter::new(out_file), out_path)?;
    let file = out
        .into_inner()
        .map_err(|e| Error::io("write", out_path, e.into_error()))?;
    file.sync_all()
        .map_err(|e| Error::io("sync", out_path, e))?;
    Ok(report)
}

/// [`recover`] from `damaged` (a file, or bytes in memory) of `input_bytes` bytes into
/// `out`, which is returned after the new file's footer; `input` and `out_path` stand
/// for the files in the report and in errors.
pub fn recover_from_reader<W: Write + Seek>(
    mut damaged: impl Read,
    input: &Path,
    input_bytes: u64,
    out: W,
    out_path: &Path,
) -> Result<(RecoverReport, W)> {
    let mut out = Some(out);

    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_emit_chunks(true)
            .with_skip_end_magic(true)
            // No record is longer than the file. A crash leaves the open chunk with
            // the length the writer had not yet patched (u64::MAX), and without a
            // limit mcap 0.26 panics adding the opcode and length sizes to it.
            .with_record_length_limit(usize::try_from(input_bytes).unwrap_or(usize::MAX)),
    );
    // The header comes first; the new file's header copies its profile.
    let mut copier: Option<Copier<W>> = None;
    let mut valid_prefix_bytes = mcap::MAGIC.len() as u64;
    let mut input_complete = false;
    let mut stop_reason = None;
    loop {
        let Some(event) = reader.next_event() else {
            break;
        };
        let event = match event {
            Ok(event) => event,
            Err(mcap::McapError::BadMagic) if copier.is_none() => {
                return Err(Error::Mcap {
                    path: input.to_path_buf(),
                    source: mcap::McapError::BadMagic,
                });
            }
            Err(e) => {
                stop_reason = Some(match e {
                    mcap::McapError::UnexpectedEof => format!(
                        "the file ends inside a record that starts at byte {valid_prefix_bytes}"
                    ),
                    e => format!("unreadable record at byte {valid_prefix_bytes}: {e}"),
                });
                break;
            }
        };
        match event {
            LinearReadEvent::ReadRequest(need) => {
                let n = damaged
                    .read(reader.insert(need))
                    .map_err(|e| Error::io("read", input, e))?;
                reader.notify_read(n);
            }
            LinearReadEvent::Record { opcode, data } => {
                let record_start = valid_prefix_bytes;
                valid_prefix_bytes += 1 + 8 + data.len() as u64;
                let parsed = guard::record(opcode, data)
                    .and_then(|()| mcap::parse_record(opcode, data).map_err(|e| e.to_string()));
                let record = match parsed {
                    Ok(r) => r,
                    Err(e) => {
                        valid_prefix_bytes = record_start;
                        stop_reason =
                            Some(format!("unreadable record at byte {record_start}: {e}"));
                        break;
                    }
                };
                let Some(c) = copier.as_mut() else {
                    let McapRecord::Header(h) = record else {
                        return Err(Error::Mcap {
                            path: input.to_path_buf(),
                            source: mcap::McapError::BadMagic,
                        });
                    };
                    // Taken once: there is no copier only until the header.
                    let Some(out) = out.take() else {
                        continue;
                    };
                    copier = Some(Copier::new(input, input_bytes, out_path, out, h.profile)?);
                    continue;
                };
                if let McapRecord::Chunk { header, data } = record {
                    c.copy_chunk(header, &data)?;
                } else if !c.copy(record)? {
                    input_complete = true;
                    break;
                }
            }
        }
    }
    if !input_complete && stop_reason.is_none() {
        stop_reason = Some(format!(
            "the file ends after the record ending at byte {valid_prefix_bytes}, before its data-end record"
        ));
    }

    let Some(mut copier) = copier else {
        return Err(Error::Truncated {
            path: input.to_path_buf(),
        });
    };
    copier
        .writer
        .finish()
        .map_err(|e| Error::mcap(out_path, e))?;
    let mut out = copier.writer.into_inner();
    let mut report = copier.report;
    report.output_bytes = out
        .seek(SeekFrom::End(0))
        .map_err(|e| Error::io("seek in", out_path, e))?;
    report.valid_prefix_bytes = valid_prefix_bytes;
    report.input_complete = input_complete;
    report.stop_reason = stop_reason;
    Ok((report, out))
}
