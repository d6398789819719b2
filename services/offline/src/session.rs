//! The session log an offline run writes: what `vibrocomp record` writes during a
//! lock-stepped replay (`vibro_log::record`), with the data time for both of MCAP's
//! times and no heartbeat or log line.

use crate::copy::{Copier, Sink};
use crate::{Outputs, Setup};
use anyhow::Context;
use std::collections::BTreeMap;
use std::path::Path;
use vibro_log::attachments::{LogExtras, RECORDER_METADATA, RECORDING_METADATA};
use vibro_log::{topic, Placement, Timeline};
use vibro_mcap::{
    ChannelId, Compression, Message, Reader, Record, Recorder, RecorderOptions, ViewChannelId,
};
use vibro_msgs::{CompensatedBlock, Stream, VibEstimate};
use vibro_view::{ViewBuilder, ViewMessage, UNIT_NAMES};

/// How the session is written.
#[derive(Debug, Clone, PartialEq)]
pub struct OutputOptions {
    /// Replace an existing regular file.
    pub force: bool,
    /// Write the view channels beside the wire streams (docs/view.md), as the recorder
    /// does by default.
    pub view: bool,
    /// zstd chunks, the recorder's default (else uncompressed: larger, less CPU).
    pub compress: bool,
    /// Copy the log's chunks into the session as they are, still compressed, where
    /// their records are the bytes the session would hold (a log written as a
    /// session writes them: the simulator's, a session's); else each record is
    /// written. The same messages either way; only the chunking differs.
    pub copy_chunks: bool,
}

impl Default for OutputOptions {
    fn default() -> Self {
        Self {
            force: false,
            view: true,
            compress: true,
            copy_chunks: true,
        }
    }
}

/// The streams of the session, in the recorder's order (`DEFAULT_RECORD_STREAMS`
/// without the services' heartbeats and log lines: no service runs).
const STREAMS: [Stream; 5] = [
    Stream::Vib,
    Stream::Accel,
    Stream::Truth,
    Stream::Estimate,
    Stream::Compensated,
];

/// The session's input streams: the first of `STREAMS`.
const INPUTS: usize = 3;

/// What was written.
pub(crate) struct Written {
    pub messages: BTreeMap<String, u64>,
    pub off_timeline: u64,
    pub bytes: u64,
    pub copied_chunks: u64,
}

/// The view channels: the units' (fed by `/compensated`) and the axes' (by
/// `/estimate`), as the recorder opens them for these streams.
struct View {
    builder: ViewBuilder,
    channels: BTreeMap<String, (ViewChannelId, u32)>,
    out: Vec<ViewMessage>,
}

pub(crate) struct SessionWriter {
    recorder: Recorder,
    copier: Option<Copier>,
    channels: [ChannelId; STREAMS.len()],
    counts: [u64; STREAMS.len()],
    view: Option<View>,
    view_counts: BTreeMap<String, u64>,
    timeline: Timeline,
    off_timeline: u64,
}

impl SessionWriter {
    /// Creates `path` (a part file the caller made: replaced) and writes the header
    /// records: channels, the `recording` and `recorder` metadata, the configurations
    /// and the compensator's passports (as `vibrocomp record` attaches them).
    pub(crate) fn create(
        path: &Path,
        log: &Path,
        setup: &Setup,
        options: &OutputOptions,
    ) -> anyhow::Result<Self> {
        let recorder_options = RecorderOptions {
            compression: if options.compress {
                Compression::Zstd
            } else {
                Compression::None
            },
            // One core: the writer on this thread, no hand-over per message.
            writer_thread: false,
            // The log's chunks copied as they are where they can be.
            splice: options.copy_chunks,
            ..RecorderOptions::default()
        };
        let mut recorder = Recorder::create(path, recorder_options)?;
        // The inputs' channels opened in the order of the log's channel IDs, the
        // outputs' after them: a log whose rig channels have the first IDs in another
        // order (an imported rig log: /truth, /vib, /accel) has its records on the same
        // IDs in the session, so that its chunks can be copied as they are (copy.rs).
        let mut order: Vec<usize> = (0..STREAMS.len()).collect();
        let log_ids = input_channel_ids(log);
        order[..INPUTS].sort_by_key(|&at| (log_ids[at], at));
        let mut opened: [Option<ChannelId>; STREAMS.len()] = Default::default();
        for at in order {
            let s = STREAMS[at];
            opened[at] = Some(recorder.add_channel(&topic(s), s.kind())?);
        }
        let channels = opened.map(|c| c.ok_or_else(|| anyhow::anyhow!("a channel not opened")));
        let channels: [ChannelId; STREAMS.len()] = match channels {
            [Ok(a), Ok(b), Ok(c), Ok(d), Ok(e)] => [a, b, c, d, e],
            _ => anyhow::bail!("a session channel was not opened"),
        };
        let view = if options.view {
            let mut list = BTreeMap::new();
            for (t, schema) in vibro_view::topics(UNIT_NAMES) {
                let fed = t.starts_with("/view/vibration/")
                    || UNIT_NAMES.iter().any(|u| t == format!("/view/{u}"));
                if fed {
                    let id = recorder.add_view_channel(&t, schema)?;
                    list.insert(t, (id, 0u32));
                }
            }
            let mut builder = ViewBuilder::new(UNIT_NAMES);
            let mut out = Vec::new();
            // A log with a reference: compensated blocks wait for theirs in the view,
            // as in a replay that publishes `/truth`.
            let reference = has_truth(log);
            builder.expect_reference(reference, &mut out);
            Some(View {
                builder,
                channels: list,
                out,
            })
        } else {
            None
        };
        let mut extras = LogExtras::generated();
        extras.metadata(
            RECORDING_METADATA,
            BTreeMap::from([
                ("source".to_string(), log.display().to_string()),
                ("topics".to_string(), STREAMS.map(topic).join(", ")),
                (
                    "log_time".to_string(),
                    "data time, ns: a block's last sample, an estimate's window end \
                     (docs/logs.md, Time)"
                        .to_string(),
                ),
                (
                    "publish_time".to_string(),
                    "the data time as well: an offline run (`vibrocomp log compensate`) \
                     has no receive time"
                        .to_string(),
                ),
            ]),
        );
        extras.metadata(
            RECORDER_METADATA,
            BTreeMap::from([(
                "program".to_string(),
                format!("vibrocomp {} log compensate", env!("CARGO_PKG_VERSION")),
            )]),
        );
        extras.service_config(
            "estimator",
            &setup.estimator_source,
            setup.estimator_text.clone(),
        );
        extras.service_config(
            "compensator",
            &setup.compensator_source,
            setup.compensator_text.clone(),
        );
        for (i, p) in setup.compensator.model.triad.passports.iter().enumerate() {
            let text = toml::to_string(&p.to_spec()).context("passport as TOML")?;
            extras.passport(i, p.id(), text);
        }
        extras.write_to(&recorder)?;
        Ok(Self {
            recorder,
            copier: options
                .copy_chunks
                .then(|| Copier::new(options.compress, INPUTS)),
            channels,
            counts: [0; STREAMS.len()],
            view,
            view_counts: BTreeMap::new(),
            timeline: Timeline::default(),
            off_timeline: 0,
        })
    }

    /// Writes one message at its data time, as the recorder places it, and its view
    /// messages. `input`: the log's record it is, and the reader that yielded it last,
    /// for copying the log's chunks (`copy.rs`).
    fn write(
        &mut self,
        at: usize,
        message: Message,
        seq: u64,
        input: Option<(&Record, &mut Reader)>,
    ) -> anyhow::Result<()> {
        let (log_time_ns, on_timeline) = self.place(&message);
        let mut sink = Sink {
            recorder: &self.recorder,
            channels: &self.channels,
            counts: &mut self.counts,
            view_counts: &mut self.view_counts,
        };
        if on_timeline {
            if let Some(v) = self.view.as_mut() {
                v.builder.on_message(&message, &mut v.out);
                write_view(&mut sink, self.copier.as_mut(), v, log_time_ns)?;
            }
        }
        match (self.copier.as_mut(), input) {
            (Some(c), Some((record, reader))) => {
                c.input(&mut sink, reader, record, at, log_time_ns, seq as u32)
            }
            (Some(c), None) => c.output(&mut sink, at, log_time_ns, seq as u32, &message),
            (None, _) => {
                // The writer on this thread: never `QueueFull`.
                self.recorder.write_to(
                    &self.channels[at],
                    log_time_ns,
                    log_time_ns,
                    seq as u32,
                    message,
                )?;
                self.counts[at] += 1;
                Ok(())
            }
        }
    }

    /// Where the timeline places `message`: (log time, on the timeline).
    fn place(&mut self, message: &Message) -> (u64, bool) {
        match message.data_ns() {
            Some(t) => match self.timeline.place(t) {
                Placement::On(t) | Placement::Resync(t) => (t, true),
                Placement::Off(now) => {
                    self.off_timeline += 1;
                    (now, false)
                }
            },
            None => (self.timeline.now_ns().unwrap_or(0), true),
        }
    }

    /// Flushes the view and finishes the file (its summary section).
    pub(crate) fn finish(mut self) -> anyhow::Result<Written> {
        anyhow::ensure!(
            self.copier.as_ref().is_none_or(Copier::is_empty),
            "records still held for the log's chunks (end_of_input was not called)"
        );
        if let Some(mut v) = self.view.take() {
            v.builder.flush(&mut v.out);
            let at = self.timeline.now_ns().unwrap_or(0);
            let mut sink = Sink {
                recorder: &self.recorder,
                channels: &self.channels,
                counts: &mut self.counts,
                view_counts: &mut self.view_counts,
            };
            write_view(&mut sink, self.copier.as_mut(), &mut v, at)?;
        }
        let finished = self.recorder.finish()?;
        let mut messages: BTreeMap<String, u64> = STREAMS
            .iter()
            .zip(self.counts)
            .map(|(s, n)| (topic(*s), n))
            .collect();
        messages.extend(self.view_counts);
        Ok(Written {
            messages,
            off_timeline: self.off_timeline,
            bytes: finished.bytes,
            copied_chunks: self.copier.as_ref().map_or(0, |c| c.copied_chunks),
        })
    }
}

/// The log's channel ID of each input stream (`u16::MAX`: none, or the log unreadable,
/// which `run` reports).
fn input_channel_ids(log: &Path) -> [u16; INPUTS] {
    let reader = vibro_mcap::Reader::open(log).ok();
    std::array::from_fn(|at| {
        reader
            .as_ref()
            .and_then(|r| r.channel_id(&topic(STREAMS[at])))
            .unwrap_or(u16::MAX)
    })
}

/// Whether the log has a `/truth` channel (a reference the view waits for).
fn has_truth(log: &Path) -> bool {
    let truth = topic(Stream::Truth);
    vibro_mcap::Reader::open(log)
        .map(|r| r.channels().iter().any(|(t, _)| *t == truth))
        .unwrap_or(false)
}

/// Writes what the view builder made (held behind undecided chunks: `copy.rs`);
/// publish time: the data time of the message that made them.
fn write_view(
    sink: &mut Sink<'_>,
    mut copier: Option<&mut Copier>,
    v: &mut View,
    publish_ns: u64,
) -> anyhow::Result<()> {
    for m in v.out.drain(..) {
        let Some((channel, seq)) = v.channels.get_mut(&m.topic) else {
            continue;
        };
        match copier.as_deref_mut() {
            Some(c) => c.view(sink, channel, m.log_time_ns, publish_ns, *seq, m.data)?,
            None => {
                crate::copy::write_view(sink, channel, m.log_time_ns, publish_ns, *seq, m.data)?
            }
        }
        *seq = seq.wrapping_add(1);
    }
    Ok(())
}

impl Outputs for SessionWriter {
    fn input(
        &mut self,
        stream: Stream,
        record: &Record,
        reader: &mut Reader,
    ) -> anyhow::Result<()> {
        let Some(at) = STREAMS.iter().position(|s| *s == stream) else {
            return Ok(());
        };
        let seq = match &record.message {
            Message::VibBlock(b) => b.seq,
            Message::AccelBlock(b) => b.seq,
            Message::TruthBlock(b) => b.seq,
            _ => 0,
        };
        self.write(at, record.message, seq, Some((record, reader)))
    }

    fn estimate(&mut self, estimate: &VibEstimate) -> anyhow::Result<()> {
        self.write(3, Message::VibEstimate(*estimate), estimate.seq, None)
    }

    fn compensated(&mut self, block: &CompensatedBlock) -> anyhow::Result<()> {
        self.write(4, Message::CompensatedBlock(*block), block.seq, None)
    }

    fn end_of_input(&mut self, _reader: &mut Reader) -> anyhow::Result<()> {
        let Some(c) = self.copier.as_mut() else {
            return Ok(());
        };
        let mut sink = Sink {
            recorder: &self.recorder,
            channels: &self.channels,
            counts: &mut self.counts,
            view_counts: &mut self.view_counts,
        };
        c.end(&mut sink)
    }

    fn copies_chunks(&self) -> bool {
        self.copier.is_some()
    }
}
