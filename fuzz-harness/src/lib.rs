//! # vibro-fuzz: the bodies of the fuzz targets
//!
//! One function per input surface that takes bytes from outside. The cargo-fuzz
//! targets in `fuzz/fuzz_targets/` are one-line calls of these functions (libFuzzer
//! needs nightly), and this crate's tests replay every file of `fuzz/corpus/<target>/`
//! and `fuzz/regressions/<target>/` through them on stable, so `cargo test --workspace`
//! keeps the corpora and the crashes found so far passing.
//!
//! | function | feeds the bytes to | checks |
//! |---|---|---|
//! | [`mcap_read`] | `vibro_mcap::{Reader, info, recover, Message::decode}` as an MCAP file | no panic; a recovered file reads back whole |
//! | [`mcap_recover`] | damage operations (flipped bits, zeroed or filled runs, a cut) on a small valid file ([`recovery::fixture`]) to `vibro_mcap::recover` | no panic, no read outside the file; every message whose bytes are intact kept, every message kept one of the original's ([`recovery`]) |
//! | [`csv_import`] | `vibro_log::import`'s two passes over a CSV file (`vibrocomp log import`) | no panic; blocks valid and in order; errors name the file |
//! | [`config_parse`] | every TOML parser: estimator, compensator, passport, triad, scenario, and the PSD table (CSV) | no panic; errors name the file |
//! | [`lab_table`] | bytes in any encoding as a campaign table (`vibro_lab::CampaignTable::read`, the reader of every lab command and the Python package), then `compare` and a `diagnose` of two candidates on a small budget | no panic, no hang; no more read than the cap on a line allows; a refusal names the file first and is short (at most 20 problems listed, each under 1 KiB); a fit returned is finite |
//! | [`message_validate`] | every wire type of `vibro-msgs` from raw bytes, and protobuf through `vibro_mcap` | no panic; what validates survives the protobuf round trip bit for bit |
//! | [`stream_sequence`] | an adversarial input sequence (`vibro_service::adversary`) to the compensator's and the estimator's cores | no input silences them: the real stream is taken again within 4 messages, never dropped after, and estimated again within a window; no jump or fake step counted as a loss |
//!
//! A broken invariant is a panic with the reason, which libFuzzer reports as a crash.
//!
//! ```
//! // A wire AccelBlock whose count (1000) exceeds its array: refused, no panic.
//! let mut bytes = vec![0u8; 1 + std::mem::size_of::<vibro_msgs::AccelBlock>()];
//! bytes[1 + 5 * 8 + 32 * 3 * 8..][..4].copy_from_slice(&1000u32.to_ne_bytes());
//! vibro_fuzz::message_validate(&bytes);
//! ```
//!
//! `fuzz/README.md` says how to run the targets, for how long they ran and what they
//! found.

pub mod recovery;

pub use recovery::mcap_recover;

use std::fmt::Display;
use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use vibro_log::import::{read_csv_blocks, ImportKind};
use vibro_log::rig::RigMessage;
use vibro_mcap::{Message, Reader};
use vibro_msgs::{
    AccelBlock, CompensatedBlock, CompensationMode, Heartbeat, LogLine, MessageKind, ServiceId,
    ServiceState, TruthBlock, VibBlock, VibEstimate, WireMessage,
};

/// The body of a fuzz target: bytes in, a panic if an invariant breaks.
pub type Target = fn(&[u8]);

/// The targets by name, as in `fuzz/Cargo.toml` and the corpus folders.
pub const TARGETS: [(&str, Target); 7] = [
    ("mcap_read", mcap_read),
    ("mcap_recover", mcap_recover),
    ("lab_table", lab_table),
    ("csv_import", csv_import),
    ("config_parse", config_parse),
    ("message_validate", message_validate),
    ("stream_sequence", stream_sequence),
];

/// Every message kind, in the order a selector byte picks them.
const KINDS: [MessageKind; MessageKind::ALL.len()] = MessageKind::ALL;

/// An error must say something.
fn check_error(what: &str, e: &impl Display) {
    let text = e.to_string();
    assert!(!text.trim().is_empty(), "{what}: empty error message");
}

/// An error must say something and name `name` (the file).
fn check_error_names(what: &str, e: &impl Display, name: &str) {
    let text = e.to_string();
    assert!(
        text.contains(name),
        "{what}: the error does not name the file {name:?}: {text}"
    );
}

// ---------------------------------------------------------------------------------
// MCAP

/// Arbitrary bytes as an MCAP file: read in log-time order ([`Reader`], with its
/// attachments and metadata), summarised (`info`) and recovered (`recover`); the
/// recovered file must then read back without error, with the messages the report
/// counted. The whole input is also decoded as protobuf of every wire type.
pub fn mcap_read(data: &[u8]) {
    let name = Path::new("fuzz.mcap");
    read_all(data, name);

    match vibro_mcap::info_from_reader(data, name, data.len() as u64) {
        Ok(info) => {
            assert_eq!(
                info.messages,
                info.channels.iter().map(|c| c.messages).sum::<u64>()
            );
            // Counts that cannot lie: a gap counts at most MAX_LOST_MESSAGES (a larger
            // step is a jump, not a loss), and the totals add up.
            let limit = vibro_mcap::MAX_LOST_MESSAGES;
            for c in &info.channels {
                assert!(c.lost <= c.gaps.saturating_mul(limit), "{c:?}");
                assert!(
                    c.gaps + c.jumps + c.out_of_order < c.messages.max(1),
                    "{c:?}"
                );
            }
            assert_eq!(
                info.lost,
                info.channels.iter().map(|c| c.lost).sum::<u64>() + info.inputs_without_output
            );
        }
        Err(e) => check_error("info", &e),
    }

    let out_name = Path::new("recovered.mcap");
    match vibro_mcap::recover_from_reader(
        Cursor::new(data),
        name,
        data.len() as u64,
        Cursor::new(Vec::new()),
        out_name,
    ) {
        Ok((report, out)) => {
            let out = out.into_inner();
            assert_eq!(report.output_bytes, out.len() as u64);
            let info = vibro_mcap::info_from_reader(out.as_slice(), out_name, out.len() as u64)
                .unwrap_or_else(|e| panic!("recover wrote a file that info cannot read: {e}"));
            assert_eq!(
                info.messages, report.messages_recovered,
                "recover reported other messages than it wrote"
            );
            if let Err(e) = Reader::from_reader(Cursor::new(out), out_name) {
                panic!("recover wrote a file that the reader cannot open: {e}");
            }
        }
        Err(e) => check_error("recover", &e),
    }

    for kind in KINDS {
        decode_checked(kind, data);
    }
}

/// Everything a [`Reader`] offers, over `data`.
fn read_all(data: &[u8], name: &Path) {
    let mut reader = match Reader::from_reader(Cursor::new(data.to_vec()), name) {
        Ok(r) => r,
        Err(e) => return check_error("Reader::from_reader", &e),
    };
    let _ = reader.channels();
    let _ = reader.foreign_topics();
    let _ = reader.message_count();
    for attachment in reader.attachment_names() {
        if let Err(e) = reader.read_attachment(&attachment) {
            check_error("read_attachment", &e);
        }
    }
    if let Err(e) = reader.metadata() {
        check_error("metadata", &e);
    }
    let mut last_log_time_ns = 0;
    for record in reader {
        match record {
            Ok(r) => {
                assert!(
                    r.log_time_ns >= last_log_time_ns,
                    "messages out of log-time order: {} after {last_log_time_ns}",
                    r.log_time_ns
                );
                last_log_time_ns = r.log_time_ns;
                round_trip(&r.message);
            }
            Err(e) => check_error("Reader::next", &e),
        }
    }
}

/// Protobuf bytes of `kind`: if they decode, the message is valid and round-trips.
fn decode_checked(kind: MessageKind, bytes: &[u8]) {
    match Message::decode(kind, bytes) {
        Ok(m) => {
            assert_eq!(m.kind(), kind);
            round_trip(&m);
        }
        Err(e) => check_error("Message::decode", &e),
    }
}

/// A decoded (or validated) message encodes, and decodes back to the same wire bytes.
fn round_trip(m: &Message) {
    if let Err(e) = m.validate() {
        panic!("a decoded {} does not validate: {e}", m.kind());
    }
    let mut buf = Vec::new();
    if let Err(e) = m.encode(&mut buf) {
        panic!("a valid {} does not encode: {e}", m.kind());
    }
    let back = Message::decode(m.kind(), &buf)
        .unwrap_or_else(|e| panic!("{} does not decode what it encoded: {e}", m.kind()));
    assert!(
        back.wire_bytes() == m.wire_bytes(),
        "{} changed in the protobuf round trip",
        m.kind()
    );
}

// ---------------------------------------------------------------------------------
// CSV import

/// Options that rates in the corpus can pick: the rig's rates, 1 Hz and the fastest
/// that `log import` accepts.
const RATES_HZ: [f64; 6] = [1.0, 100.0, 1000.0, 2000.0, 25_600.0, 1e9];

/// A scratch file name unique to this process and call.
fn scratch_file(extension: &str) -> PathBuf {
    static NEXT: AtomicU64 = AtomicU64::new(0);
    std::env::temp_dir().join(format!(
        "vibro-fuzz-{}-{}.{extension}",
        std::process::id(),
        NEXT.fetch_add(1, Ordering::Relaxed)
    ))
}

/// Three option bytes, then a CSV file for `vibrocomp log import`: byte 0 picks the
/// stream (bit 0: vib, else accel) and whether a rate is given (bit 1; bits 2..4 pick
/// it from [`RATES_HZ`]); byte 1 the samples per block (1..=capacity); byte 2 the
/// period tolerance (0 < F < 0.5). Every block must be valid, within the block size,
/// and after the previous one in samples and time; an error must name the file.
pub fn csv_import(data: &[u8]) {
    let [options, block, tolerance, csv @ ..] = data else {
        return;
    };
    let kind = if options & 1 == 1 {
        ImportKind::Vib
    } else {
        ImportKind::Accel
    };
    let rate_hz = (options & 2 == 2).then(|| RATES_HZ[usize::from(options >> 2) % RATES_HZ.len()]);
    let capacity = match kind {
        ImportKind::Accel => vibro_msgs::ACCEL_BLOCK_MAX,
        ImportKind::Vib => vibro_msgs::VIB_BLOCK_MAX,
    };
    let block_samples = 1 + usize::from(*block) % capacity;
    let tolerance = (f64::from(*tolerance) + 1.0) / 257.0 * 0.5;

    let file = scratch_file("csv");
    if let Err(e) = std::fs::write(&file, csv) {
        panic!("cannot write the scratch file {}: {e}", file.display());
    }
    let mut next_index = 0u64;
    let mut last_t0_ns = 0u64;
    let mut blocks = 0u64;
    let result = read_csv_blocks(kind, &file, rate_hz, block_samples, tolerance, |m| {
        let (first, count, t0_ns, valid) = match &m {
            RigMessage::Accel(b) => (b.first_sample_index, b.count, b.t0_ns, b.validate()),
            RigMessage::Vib(b) => (b.first_sample_index, b.count, b.t0_ns, b.validate()),
            RigMessage::Truth(b) => (b.first_sample_index, b.count, b.t0_ns, b.validate()),
        };
        if let Err(e) = valid {
            panic!("block {blocks} does not validate: {e}");
        }
        assert!(
            (1..=block_samples as u32).contains(&count),
            "block {blocks} has {count} samples, the block size is {block_samples}"
        );
        assert!(
            first >= next_index && (blocks == 0 || t0_ns > last_t0_ns),
            "block {blocks} (sample {first}, t0 {t0_ns} ns) is not after the previous one (sample {next_index}, t0 {last_t0_ns} ns)"
        );
        let _ = m.time_ns();
        next_index = first + u64::from(count);
        last_t0_ns = t0_ns;
        blocks += 1;
    });
    let _ = std::fs::remove_file(&file);
    match result {
        Ok(n) => assert_eq!(
            n, blocks,
            "read_csv_blocks counted other blocks than it gave"
        ),
        Err(e) => {
            let name = file.display().to_string();
            check_error_names("log import", &format!("{e:#}"), &name);
        }
    }
}

// ---------------------------------------------------------------------------------
// configuration

/// UTF-8 text through every configuration parser: the estimator's and the
/// compensator's service configuration, an accelerometer passport, a triad, a
/// simulator scenario (TOML) and a PSD table (CSV). Each is `Ok` or an error that
/// names the file.
pub fn config_parse(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    use vibro_service::{ConfigSource, ServiceConfig};
    const INLINE: &str = "inline configuration";
    if let Err(e) = vibro_estimator::Config::parse(text, ConfigSource::Inline) {
        check_error_names("estimator config", &e, INLINE);
    }
    if let Err(e) = vibro_compensator::Config::parse(text, ConfigSource::Inline) {
        check_error_names("compensator config", &e, INLINE);
    }
    const FILE: &str = "fuzz.toml";
    if let Err(e) = vibro_config::parse_passport(text, FILE) {
        check_error_names("passport", &e, FILE);
    }
    if let Err(e) = vibro_config::parse_triad(text, FILE) {
        check_error_names("triad", &e, FILE);
    }
    if let Err(e) = vibro_config::parse_psd_table(text, "fuzz.csv") {
        check_error_names("PSD table", &e, "fuzz.csv");
    }
    if let Err(e) = vibro_sim::parse_scenario(text, FILE, None) {
        check_error_names("scenario", &e, FILE);
    }
}

// ---------------------------------------------------------------------------------
// stream sequences

/// Steps of an adversarial prefix [`stream_sequence`] reads at most.
const SEQUENCE_MAX_STEPS: usize = 64;

/// The estimator [`stream_sequence`] runs: 4096 Hz, so that a window (1 s) is 8 blocks
/// of 512 samples and a run stays fast.
const SEQUENCE_ESTIMATOR: &str =
    "[estimator]\nsample_rate_hz = 4096.0\nsensitivity_raw_per_g = [0.1, 0.1, 0.1]\n";

/// Bytes as an adversarial input sequence (`vibro_service::adversary::generate`): byte
/// 0 picks the mode (bit 0: isolated episodes, [`vibro_service::adversary::Sequence`]),
/// the rest, 8 bytes a step, up to [`SEQUENCE_MAX_STEPS`] steps of the prefix (seq and
/// sample-index jumps both ways, repeats, reorderings, time jumps, `u64::MAX`, 0,
/// absurd values, fake bursts and streams); then the real stream alone. The sequence
/// goes as accelerometer blocks (32 samples, 800 Hz) to the compensator's core and as
/// vibration blocks (512 samples, 4096 Hz) to the estimator's core, both in-process
/// (the services' own per-message code). Checks (`adversary::check`): the real stream
/// is taken again within `RESYNC_AFTER` (4) messages and never dropped after (the
/// compensator: a block taken is a block answered); with isolated episodes, no more
/// messages counted lost than real ones never taken; the estimator takes every tail
/// block its continuity takes, and its first estimate comes within `RESYNC_AFTER - 1`
/// blocks plus a window (8 blocks) of the tail's start.
pub fn stream_sequence(data: &[u8]) {
    use vibro_msgs::accel_flags;
    use vibro_service::adversary::{check, generate};
    use vibro_service::{ConfigSource, ServiceConfig, RESYNC_AFTER};
    static CONFIGS: std::sync::OnceLock<(vibro_compensator::Config, vibro_estimator::Config)> =
        std::sync::OnceLock::new();
    let [mode, rest @ ..] = data else {
        return;
    };
    let (comp_config, est_config) = CONFIGS.get_or_init(|| {
        (
            vibro_compensator::Config::shipped().expect("the shipped compensator configuration"),
            vibro_estimator::Config::parse(SEQUENCE_ESTIMATOR, ConfigSource::Inline)
                .expect("the stream_sequence estimator configuration"),
        )
    });
    let mut words = rest.chunks(8).map(|c| {
        let mut w = [0u8; 8];
        w[..c.len()].copy_from_slice(c);
        u64::from_le_bytes(w)
    });

    // The compensator.
    let s = generate(|| words.next(), SEQUENCE_MAX_STEPS, 32, mode & 1 != 0);
    let mut comp = vibro_compensator::InProcess::new(comp_config).expect("the compensator core");
    let k1 = comp_config.model.k1_v_per_g();
    let mut out = Vec::new();
    let taken: Vec<bool> = s
        .messages
        .iter()
        .map(|m| {
            let mut b = AccelBlock::ZEROED;
            b.seq = m.seq;
            b.first_sample_index = m.first_sample_index;
            b.sample_period_ns = 1_250_000;
            b.t0_ns = m.t0_periods.saturating_mul(b.sample_period_ns);
            b.count = 32;
            for (k, v) in b.output_v[..32].iter_mut().enumerate() {
                let g = 1.0 + 0.01 * (k as f64 * 0.7).sin();
                *v = [0.1 * g * k1[0], -0.2 * g * k1[1], g * k1[2]];
            }
            if m.absurd_values {
                b.output_v[5] = [f64::NAN, 1e300, f64::NEG_INFINITY];
                b.flags = accel_flags::SATURATED;
            }
            let before = out.len();
            comp.on_accel(&b, 0, &mut out);
            out.len() > before
        })
        .collect();
    let summary = comp.summary();
    if let Err(e) = check(&s, &taken, summary.accel.lost_messages) {
        panic!("compensator: {e} ({:?})", summary.accel);
    }

    // The estimator, on the same steps with blocks of 512 samples.
    let mut words = rest.chunks(8).map(|c| {
        let mut w = [0u8; 8];
        w[..c.len()].copy_from_slice(c);
        u64::from_le_bytes(w)
    });
    const VIB_SAMPLES: usize = 512;
    let s = generate(
        || words.next(),
        SEQUENCE_MAX_STEPS,
        VIB_SAMPLES as u64,
        mode & 1 != 0,
    );
    let estimator = &est_config.estimator;
    let period_ns = estimator.sample_period_ns().round() as u64;
    let window_blocks = estimator.window_samples().div_ceil(VIB_SAMPLES);
    let mut core = vibro_estimator::InProcess::new(estimator).expect("the estimator core");
    let mut estimates: Vec<VibEstimate> = Vec::new();
    let mut taken = Vec::with_capacity(s.messages.len());
    let mut first_estimate = None;
    for (i, m) in s.messages.iter().enumerate() {
        let mut b = VibBlock::ZEROED;
        b.seq = m.seq;
        b.first_sample_index = m.first_sample_index;
        b.sample_period_ns = period_ns;
        b.t0_ns = m.t0_periods.saturating_mul(period_ns);
        b.count = VIB_SAMPLES as u32;
        for (k, v) in b.sample_v[..VIB_SAMPLES].iter_mut().enumerate() {
            let phase = (m.first_sample_index.wrapping_add(k as u64) % 4096) as f64;
            let x = 0.1 * (std::f64::consts::TAU * 97.0 * phase / 4096.0).sin();
            *v = [x, 0.5 * x, -x];
        }
        if m.absurd_values {
            b.sample_v[9] = [f64::NAN, 1e300, f64::INFINITY];
        }
        let out_of_order = core.counters().vib.out_of_order;
        let accepted = core.dsp_counters().blocks_accepted;
        let before = estimates.len();
        core.on_block(&b, 0, &mut estimates)
            .expect("the estimator fails only on an internal FFT error");
        let took = core.counters().vib.out_of_order == out_of_order;
        taken.push(took);
        if i >= s.tail {
            assert!(
                !took || core.dsp_counters().blocks_accepted == accepted + 1,
                "estimator: tail block {} taken by the continuity, dropped by the estimator",
                i - s.tail
            );
            if first_estimate.is_none() && estimates.len() > before {
                first_estimate = Some(i - s.tail);
            }
        }
    }
    if let Err(e) = check(&s, &taken, core.summary().vib.lost_messages) {
        panic!("estimator: {e} ({:?})", core.summary().vib);
    }
    let bound = RESYNC_AFTER as usize - 1 + window_blocks;
    assert!(
        first_estimate.is_some_and(|k| k <= bound),
        "estimator: first estimate at tail block {first_estimate:?}, bound {bound}"
    );
}

// ---------------------------------------------------------------------------------
// wire messages

/// Byte 0 picks a message kind (`% 6`, in [`MessageKind`] order) and, with bit 7, the
/// encoding of the rest: raw wire bytes (clear) or protobuf (set). Wire bytes are read
/// with `from_bytes`, exactly as given and cut or zero-padded to the struct's size,
/// then validated; a valid message must survive the protobuf round trip with every
/// byte that matters (the valid slots; the rest and the padding come back zeroed), an
/// invalid one must be refused by the encoder. Protobuf must decode to a valid message
/// that round-trips, or fail cleanly.
pub fn message_validate(data: &[u8]) {
    let [selector, rest @ ..] = data else {
        return;
    };
    let kind = KINDS[usize::from(selector & 0x7F) % KINDS.len()];
    if selector & 0x80 != 0 {
        return decode_checked(kind, rest);
    }
    match kind {
        MessageKind::AccelBlock => wire::<AccelBlock>(rest, AccelBlock::from_bytes),
        MessageKind::VibBlock => wire::<VibBlock>(rest, VibBlock::from_bytes),
        MessageKind::VibEstimate => wire::<VibEstimate>(rest, VibEstimate::from_bytes),
        MessageKind::CompensatedBlock => {
            wire::<CompensatedBlock>(rest, CompensatedBlock::from_bytes)
        }
        MessageKind::TruthBlock => wire::<TruthBlock>(rest, TruthBlock::from_bytes),
        MessageKind::Heartbeat => wire::<Heartbeat>(rest, Heartbeat::from_bytes),
        MessageKind::LogLine => wire::<LogLine>(rest, LogLine::from_bytes),
    }
}

/// A wire type read from `bytes` and checked.
fn wire<T>(bytes: &[u8], from_bytes: fn(&[u8]) -> Option<T>)
where
    T: WireMessage + Normalise + Into<Message>,
{
    let size = std::mem::size_of::<T>();
    assert_eq!(
        from_bytes(bytes).is_some(),
        bytes.len() == size,
        "from_bytes of {} bytes, the struct has {size}",
        bytes.len()
    );
    let mut exact = bytes[..bytes.len().min(size)].to_vec();
    exact.resize(size, 0);
    let Some(m) = from_bytes(&exact) else {
        panic!("from_bytes refused exactly {size} bytes");
    };
    assert!(
        m.bytes() == exact.as_slice(),
        "from_bytes changed the bytes"
    );
    let valid = m.validate();
    let message: Message = m.into();
    let mut buf = Vec::new();
    let encoded = message.encode(&mut buf);
    match (valid, encoded) {
        (Ok(()), Ok(())) => {
            let back = Message::decode(T::KIND, &buf)
                .unwrap_or_else(|e| panic!("{} does not decode what it encoded: {e}", T::KIND));
            let expected: Message = m.normalised().into();
            assert!(
                back.wire_bytes() == expected.wire_bytes(),
                "{} changed in the protobuf round trip",
                T::KIND
            );
        }
        (Ok(()), Err(e)) => panic!("a valid {} does not encode: {e}", T::KIND),
        (Err(e), Ok(())) => panic!("an invalid {} was encoded ({e})", T::KIND),
        (Err(e), Err(_)) => check_error("validate", &e),
    }
    m.check_codes();
}

/// What of a valid message the protobuf form carries: the valid slots, with the
/// unused ones and the padding zeroed.
trait Normalise: Sized {
    fn normalised(&self) -> Self;
    /// The coded `u8` fields convert to their enums or to an error, never a panic.
    fn check_codes(&self) {}
}

impl Normalise for AccelBlock {
    fn normalised(&self) -> Self {
        let mut m = *self;
        m.output_v[m.count as usize..].fill([0.0; 3]);
        m._pad = [0; 4];
        m
    }
}

impl Normalise for VibBlock {
    fn normalised(&self) -> Self {
        let mut m = *self;
        m.sample_v[m.count as usize..].fill([0.0; 3]);
        m._pad = [0; 4];
        m
    }
}

impl Normalise for VibEstimate {
    fn normalised(&self) -> Self {
        let mut m = *self;
        let t = m.tone_count as usize;
        m.tone_frequency_hz[t..].fill(0.0);
        m.tone_frequency_u_hz[t..].fill(0.0);
        m.tone_amplitude_g[t..].fill([0.0; 3]);
        m.tone_amplitude_u_g[t..].fill([0.0; 3]);
        m.tone_phase_rad[t..].fill([0.0; 3]);
        m.tone_phase_u_rad[t..].fill([0.0; 3]);
        m.tone_snr_db[t..].fill([0.0; 3]);
        let b = m.band_count as usize;
        m.band_f_lo_hz[b..].fill(0.0);
        m.band_f_hi_hz[b..].fill(0.0);
        m.band_psd_g2_per_hz[b..].fill([0.0; 3]);
        m.band_psd_u_g2_per_hz[b..].fill([0.0; 3]);
        m.band_rms_g[b..].fill([0.0; 3]);
        m
    }
}

impl Normalise for CompensatedBlock {
    fn normalised(&self) -> Self {
        let mut m = *self;
        let n = m.count as usize;
        for stage in m.stages_mut() {
            stage[n..].fill([0.0; 3]);
        }
        m._pad = [0; 3];
        m
    }

    fn check_codes(&self) {
        if let Err(e) = CompensationMode::try_from(self.mode) {
            check_error_names("CompensatedBlock.mode", &e, "CompensatedBlock.mode");
        }
    }
}

impl Normalise for TruthBlock {
    fn normalised(&self) -> Self {
        let mut m = *self;
        let n = m.count as usize;
        m.a_l_ia_g[n..].fill([0.0; 3]);
        m.a_sensed_ia_g[n..].fill([0.0; 3]);
        m.vib_error_ia_g[n..].fill([0.0; 3]);
        m._pad = [0; 4];
        m
    }
}

impl Normalise for LogLine {
    fn normalised(&self) -> Self {
        let mut m = *self;
        m.text[usize::from(m.len).min(vibro_msgs::LOG_TEXT_MAX)..].fill(0);
        m._pad = [0; 4];
        m
    }

    fn check_codes(&self) {
        if let Err(e) = ServiceId::try_from(self.service) {
            check_error_names("LogLine.service", &e, "Heartbeat.service");
        }
        if let Err(e) = vibro_msgs::LogLevel::try_from(self.level) {
            check_error_names("LogLine.level", &e, "LogLine.level");
        }
    }
}

impl Normalise for Heartbeat {
    fn normalised(&self) -> Self {
        let mut m = *self;
        m._pad = [0; 6];
        m
    }

    fn check_codes(&self) {
        if let Err(e) = ServiceId::try_from(self.service) {
            check_error_names("Heartbeat.service", &e, "Heartbeat.service");
        }
        if let Err(e) = ServiceState::try_from(self.state) {
            check_error_names("Heartbeat.state", &e, "Heartbeat.state");
        }
    }
}

// ---------------------------------------------------------------------------------
// Lab campaign table

/// Where the first line longer than `cap` bytes starts (any line ending ends a line).
fn first_long_line(data: &[u8], cap: usize) -> Option<usize> {
    let mut start = 0;
    for line in data.split(|&b| b == b'\n' || b == b'\r') {
        if line.len() > cap {
            return Some(start);
        }
        start += line.len() + 1;
    }
    None
}

/// Rows a [`lab_table`] input may have for its fits to run (more: parsed only).
const LAB_MAX_FIT_ROWS: usize = 16;

/// Bytes as a campaign table (`vibrocomp lab`, docs/lab.md), named `fuzz.csv`, in
/// whatever encoding they are (UTF-8, Latin-1 bytes, UTF-16, NUL bytes, any line
/// ending): read by `CampaignTable::read` with the base model (exact mode, no default
/// passport); a table that reads is compared, and when it has at most
/// [`LAB_MAX_FIT_ROWS`] rows diagnosed with two candidates (`mount_resonance`,
/// `sensor_error`) on one thread and a small budget (200 evaluations per fit, 5 s),
/// which keeps a run fast. Checks: no panic (nalgebra's SVD panics on NaN: the lab
/// must not hand it one); no more of the input read than up to the cap on a line and a
/// buffer past the first line over it (memory bounded); a refusal names the file first
/// and is short (at most 20 problems listed and a count, each under 1 KiB: hostile
/// input is quoted by its excerpt); every fit returned is finite; the budget's report
/// adds up. (`shared/vibro-lab/tests/table_reader.rs` draws tables of every shape
/// and damage for the same properties on stable.)
pub fn lab_table(data: &[u8]) {
    use vibro_lab::table_input::{MAX_LINE_BYTES, MAX_LISTED_PROBLEMS};
    let model = vibro_lab::LabModel::base(vibro_lab::BaseMode::Exact);
    let mut input = Cursor::new(data);
    let read = vibro_lab::CampaignTable::read(
        &mut input,
        Path::new("fuzz.csv"),
        Path::new("/nonexistent-fuzz-dir"),
        &model,
    );
    if let Some(start) = first_long_line(data, MAX_LINE_BYTES) {
        // The reader's buffer is 64 KiB; a byte order mark is read before it.
        let bound = start + MAX_LINE_BYTES + 2 * (1 << 16) + 3;
        assert!(
            input.position() as usize <= bound,
            "lab table: {} bytes read, the first line over the cap starts at {start}",
            input.position()
        );
        assert!(read.is_err(), "lab table: a line over the cap was read");
    }
    let table = match read {
        Ok(t) => t,
        Err(e) => {
            let text = e.to_string();
            assert!(text.starts_with("fuzz.csv"), "lab table: {text}");
            let problems: Vec<&str> = text.split("\n  ").collect();
            assert!(
                problems.len() <= MAX_LISTED_PROBLEMS + 1,
                "lab table: {} problems listed",
                problems.len()
            );
            for p in problems {
                assert!(
                    p.len() < 1024,
                    "lab table: a problem of {} bytes: {p}",
                    p.len()
                );
            }
            return;
        }
    };
    match vibro_lab::compare(&model, &table) {
        Ok(c) => assert_eq!(c.rows.len(), table.conditions.len(), "compare: rows lost"),
        Err(e) => check_error("lab compare", &e),
    }
    if table.conditions.len() > LAB_MAX_FIT_ROWS {
        return;
    }
    let opts = vibro_lab::DiagnoseOptions {
        candidates: vec!["mount_resonance".into(), "sensor_error".into()],
        threads: 1,
        budget: vibro_lab::Budget {
            max_evaluations: 200,
            time_s: 5.0,
        },
        ..vibro_lab::DiagnoseOptions::default()
    };
    match vibro_lab::diagnose(&model, &table, &opts) {
        Ok(d) => {
            let mut evaluations = 0;
            for c in &d.candidates {
                if let Some(f) = &c.fit {
                    assert!(
                        f.chi2_after.is_finite() && f.delta_bic.is_finite(),
                        "lab diagnose: {} fitted to a non-finite chi2 {} / delta BIC {}",
                        f.kind,
                        f.chi2_after,
                        f.delta_bic
                    );
                    assert!(f.params.iter().all(|p| p.value.is_finite()), "{f:?}");
                    evaluations += f.evaluations;
                }
            }
            assert!(d.budget.evaluations >= evaluations, "{:?}", d.budget);
            assert_eq!(d.budget.exhausted, !d.budget.cut_short.is_empty());
        }
        Err(e) => check_error("lab diagnose", &e),
    }
}

#[cfg(test)]
mod tests {
    use super::TARGETS;
    use std::path::Path;

    /// Every file of `fuzz/<dir>/<target>/` through its target; a missing corpus fails.
    fn replay(dir: &str, required: bool) {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../fuzz")
            .join(dir);
        for (target, run) in TARGETS {
            let folder = root.join(target);
            let entries = match std::fs::read_dir(&folder) {
                Ok(entries) => entries,
                Err(e) if !required && e.kind() == std::io::ErrorKind::NotFound => continue,
                Err(e) => panic!("{}: {e}", folder.display()),
            };
            let mut files: Vec<_> = entries.map(|e| e.unwrap().path()).collect();
            files.sort();
            assert!(
                !(required && files.is_empty()),
                "{}: empty",
                folder.display()
            );
            for file in files {
                let data = std::fs::read(&file).unwrap();
                eprintln!("{target}: {}", file.display());
                run(&data);
            }
        }
    }

    #[test]
    fn every_corpus_input_passes() {
        replay("corpus", true);
    }

    #[test]
    fn every_fixed_crash_passes() {
        replay("regressions", false);
    }

    /// Writes the seed inputs the corpora started from into `fuzz/corpus/<target>/`
    /// (`seed-*` files; the fuzzer's own inputs are named by their hash):
    /// `cargo test -p vibro-fuzz -- --ignored write_seed_corpus`.
    #[test]
    #[ignore = "writes fuzz/corpus; run by hand to re-seed"]
    fn write_seed_corpus() {
        let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let corpus = repo.join("fuzz/corpus");
        let write = |target: &str, name: &str, data: &[u8]| {
            let dir = corpus.join(target);
            std::fs::create_dir_all(&dir).unwrap();
            std::fs::write(dir.join(format!("seed-{name}")), data).unwrap();
        };
        for (name, data) in seeds::messages() {
            write("message_validate", &name, &data);
        }
        for (name, data) in seeds::mcap_files() {
            write("mcap_read", &name, &data);
        }
        for (name, data) in seeds::recover_damage() {
            write("mcap_recover", name, &data);
        }
        for (name, data) in seeds::csv_files() {
            write("csv_import", name, &data);
        }
        for (name, data) in seeds::stream_sequences() {
            write("stream_sequence", &name, &data);
        }
        for dir in [
            "accelerometers",
            "triads",
            "services",
            "scenarios",
            "vibration",
        ] {
            for entry in std::fs::read_dir(repo.join("config").join(dir)).unwrap() {
                let path = entry.unwrap().path();
                let name = path.file_name().unwrap().to_string_lossy().into_owned();
                if name.ends_with(".toml") || name.ends_with(".csv") {
                    write("config_parse", &name, &std::fs::read(&path).unwrap());
                }
            }
        }
    }

    mod seeds {
        use std::collections::BTreeMap;
        use vibro_mcap::{Compression, Message, Recorder, RecorderOptions};
        use vibro_msgs::*;

        /// One plausible message of every kind, counts small.
        fn samples() -> Vec<Message> {
            let mut a = AccelBlock::ZEROED;
            a.seq = 7;
            a.t0_ns = 1_250_000;
            a.sample_period_ns = 1_250_000;
            a.count = 2;
            a.output_v[..2].copy_from_slice(&[[-1.6698, -1.67, 0.01], [-1.6697, -1.6701, 0.02]]);
            let mut v = VibBlock::ZEROED;
            v.seq = 3;
            v.sample_period_ns = 39_062;
            v.count = 3;
            v.sample_v[..3].copy_from_slice(&[
                [0.1, -0.2, 0.3],
                [0.0, -0.0, 1e-300],
                [2.0, 3.0, 4.0],
            ]);
            let mut e = VibEstimate::ZEROED;
            e.seq = 1;
            e.samples = 8192;
            e.valid_samples = 8192;
            e.broadband_rms_g = [1.4, 1.4, 1.4];
            e.tone_count = 1;
            e.tone_frequency_hz[0] = 12.0;
            e.tone_amplitude_g[0] = [0.5, 1.2, 1.2];
            e.band_count = 2;
            e.band_f_lo_hz[..2].copy_from_slice(&[20.0, 40.0]);
            e.band_f_hi_hz[..2].copy_from_slice(&[40.0, 80.0]);
            e.band_psd_g2_per_hz[0] = [0.017; 3];
            let mut c = CompensatedBlock::ZEROED;
            c.seq = 2;
            c.count = 1;
            c.a1_g[0] = [1e-4, 2e-4, 3e-4];
            c.main_g[0] = [1.0, 0.0, 0.0];
            c.mode = CompensationMode::Exact.code();
            let mut t = TruthBlock::ZEROED;
            t.count = 2;
            t.a_l_ia_g[..2].copy_from_slice(&[[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]);
            let mut h = Heartbeat::ZEROED;
            h.seq = 9;
            h.service = ServiceId::Compensator.code();
            h.state = ServiceState::Running.code();
            vec![a.into(), v.into(), e.into(), c.into(), t.into(), h.into()]
        }

        /// `message_validate` inputs: each sample as wire bytes and as protobuf.
        pub fn messages() -> Vec<(String, Vec<u8>)> {
            let mut out = Vec::new();
            for (k, m) in samples().iter().enumerate() {
                let mut wire = vec![k as u8];
                wire.extend_from_slice(m.wire_bytes());
                out.push((format!("{}-wire", m.kind()), wire));
                let mut proto = vec![0x80 | k as u8];
                let mut buf = Vec::new();
                m.encode(&mut buf).unwrap();
                proto.extend_from_slice(&buf);
                out.push((format!("{}-protobuf", m.kind()), proto));
            }
            out
        }

        /// `mcap_read` inputs: a recording of every kind, uncompressed (so that the
        /// fuzzer can reach the records inside chunks) and zstd, and each cut in half
        /// (a crash, for `recover`).
        pub fn mcap_files() -> Vec<(String, Vec<u8>)> {
            let mut out = Vec::new();
            for (name, compression) in [("none", Compression::None), ("zstd", Compression::Zstd)] {
                let path = std::env::temp_dir().join(format!(
                    "vibro-fuzz-seed-{}-{name}.mcap",
                    std::process::id()
                ));
                let options = RecorderOptions {
                    compression,
                    ..RecorderOptions::default()
                };
                let mut rec = Recorder::create(&path, options).unwrap();
                for (i, m) in samples().into_iter().enumerate() {
                    let topic = format!("/t{i}");
                    let channel = rec.add_channel(&topic, m.kind()).unwrap();
                    let t = 1_000 * i as u64;
                    rec.write_to(&channel, t, t, i as u32, m).unwrap();
                }
                rec.add_attachment("triad.toml", "application/toml", b"id = \"x\"\n".to_vec())
                    .unwrap();
                rec.add_metadata("run", BTreeMap::from([("k".to_string(), "v".to_string())]))
                    .unwrap();
                rec.finish().unwrap();
                let bytes = std::fs::read(&path).unwrap();
                std::fs::remove_file(&path).unwrap();
                out.push((
                    format!("{name}-cut.mcap"),
                    bytes[..bytes.len() / 2].to_vec(),
                ));
                out.push((format!("{name}.mcap"), bytes));
            }
            out
        }

        /// `mcap_recover` inputs: no damage, one operation of each kind, three at once.
        pub fn recover_damage() -> Vec<(&'static str, Vec<u8>)> {
            vec![
                ("none", vec![]),
                ("flip", vec![0, 0x04, 0x00, 0xFF]),
                ("zeros", vec![1, 0x02, 0x00, 15]),
                ("fill", vec![2, 0x06, 0x00, 0x06]),
                ("cut", vec![3, 0x08, 0x00, 0]),
                (
                    "three",
                    vec![0, 0x00, 0x30, 0x80, 1, 0x03, 0x10, 40, 3, 0x0A, 0x00, 0],
                ),
            ]
        }

        /// `stream_sequence` inputs: issue 31 (a real stream of 11 messages, one fake
        /// 999 ahead, then the stream), and seeded random steps in both modes.
        pub fn stream_sequences() -> Vec<(String, Vec<u8>)> {
            let word = |v: u64| v.to_le_bytes();
            let mut issue31 = vec![1u8];
            issue31.extend(word(0));
            for _ in 0..11 {
                issue31.extend(word(0));
            }
            // Step 6 with an offset of 998: a fake 999 ahead of the stream.
            issue31.extend(word(6 | (998 << 16)));
            let mut out = vec![("issue31".to_string(), issue31)];
            for seed in 1..=3u64 {
                for mode in [0u8, 1] {
                    let mut rng = vibro_service::adversary::Xorshift::new(seed);
                    let mut data = vec![mode];
                    for _ in 0..40 {
                        data.extend(word(rng.next_u64()));
                    }
                    out.push((format!("random-{seed}-mode{mode}"), data));
                }
            }
            out
        }

        /// `csv_import` inputs: option bytes, then a small file of each stream, with
        /// the features of docs/logs.md (comments, quotes, CRLF, a byte-order mark, an
        /// extra column, a gap).
        pub fn csv_files() -> Vec<(&'static str, Vec<u8>)> {
            let mut accel = String::from("# rig 1, AL-15 triad\ntime_s,u1_v,u2_v,u3_v\n");
            for i in 0..40 {
                let t = 0.00125 * f64::from(i + if i >= 20 { 3 } else { 0 });
                accel += &format!("{t},-1.6698,-1.6701,{}\n", 0.001 * f64::from(i));
            }
            let mut vib = String::from("\u{feff}\"time_s\",vd2_v,vd1_v,vd3_v,temp_c\r\n");
            for i in 0..70 {
                vib += &format!("{:.9},0.1,-0.2,{},21.5\r\n", f64::from(i) / 25_600.0, i % 7);
                if i == 30 {
                    vib += "\r\n# pause\r\n";
                }
            }
            let bad = "time_s,u1_v,u2_v,u3_v\n0,1,2\n0.001,nan,2,3\n0.0005,1,2,3\n".to_string();
            vec![
                (
                    "accel.csv",
                    [&[0x00, 31, 51][..], accel.as_bytes()].concat(),
                ),
                (
                    "accel-rate.csv",
                    [&[0x0A, 7, 51][..], accel.as_bytes()].concat(),
                ),
                ("vib.csv", [&[0x01, 15, 51][..], vib.as_bytes()].concat()),
                ("bad.csv", [&[0x00, 31, 51][..], bad.as_bytes()].concat()),
            ]
        }
    }
}
