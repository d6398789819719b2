//! # vibro-msgs: the message contracts of vibrocomp
//!
//! The wire types that the services exchange through iceoryx2 shared memory (and that
//! `vibro-mcap` records): accelerometer output blocks, vibration-sensor blocks,
//! vibration estimates, compensated blocks, simulator truth and heartbeats, plus the
//! service names they travel on, and the rule every reader of their `seq` counters
//! applies ([`continuity`]: gaps, jumps, resyncs and the losses they take back).
//!
//! Every type is `#[repr(C)]`, fixed-size, made of plain numbers only (no pointers,
//! strings or vectors), `Copy`, free of implicit padding (checked at compile time), and
//! derives iceoryx2's `ZeroCopySend` with an explicit, versioned type name
//! (`vibrocomp::AccelBlock::v5`). Field names carry units (`_v`, `_g`, `_hz`, `_ns`,
//! `_rad`, `_db`). Their byte layouts are published in `docs/messages.md` for rigs written
//! in C or Python, and a test checks that document against [`FieldLayout`] tables made by
//! `core::mem::offset_of!`, so the two cannot drift.
//!
//! ## Example
//!
//! ```no_run
//! use iceoryx2::prelude::*;
//! use vibro_msgs::{AccelBlock, ServiceNames, Stream};
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let names = ServiceNames::new("vibrocomp/")?;
//! let node = NodeBuilder::new().create::<ipc::Service>()?;
//! let service = node
//!     .service_builder(&names.service_name(Stream::Accel)?)
//!     .publish_subscribe::<AccelBlock>()
//!     .open_or_create()?;
//! let publisher = service.publisher_builder().create()?;
//!
//! let mut block = AccelBlock::ZEROED;
//! block.sample_period_ns = 1_000_000; // 1 kHz output rate
//! block.output_v[0] = [-1.6698, -1.6701, -1.6695];
//! block.count = 1;
//! publisher.send_copy(block)?;
//! # Ok(())
//! # }
//! ```
//!
//! ## References
//!
//! - MODEL.md (symbols `aL3`, `aB_i`, `sigma_i`, stages `a(1)`..`a(4)` of [P2 (17)-(20)])
//!   and RIG.md (the triad of accelerometers AK1..AK3 with vibration sensors VD1..VD3).
//! - iceoryx2 0.10 payload types: `ZeroCopySend`, `#[type_name]`
//!   (<https://docs.rs/iceoryx2/0.10.0>).

#[cfg(any(test, feature = "testing"))]
pub mod adversary;
pub mod continuity;
mod layout;
mod messages;
mod names;

pub use continuity::{
    Arrival, Continuity, SeqTally, StreamCounters, MAX_LOST_MESSAGES, MAX_LOST_SAMPLES,
    RESYNC_AFTER,
};
pub use layout::{FieldLayout, Plain};
pub use messages::{
    accel_flags, compensation_flags, estimate_flags, truth_flags, vib_flags, AccelBlock,
    CompensatedBlock, CompensationMode, Heartbeat, LogLevel, LogLine, MessageKind, ServiceId,
    ServiceState, TruthBlock, VibBlock, VibEstimate, WireMessage,
};
pub use names::{
    max_suffix_len, ServiceNames, Stream, DEFAULT_PREFIX, EVENT_SUFFIX, MAX_SERVICE_NAME_LEN,
};

/// Version of the message contracts. Every type name ends in `::v{SCHEMA_VERSION}`; any
/// change to any wire type's layout or meaning increments it (docs/messages.md).
pub const SCHEMA_VERSION: u32 = 5;

/// Units in a triad: accelerometers AK1..AK3, each with its vibration sensor VD1..VD3.
pub const UNITS: usize = 3;
/// Most accelerometer samples per [`AccelBlock`], [`CompensatedBlock`] and [`TruthBlock`].
pub const ACCEL_BLOCK_MAX: usize = 32;
/// Most vibration-sensor samples per [`VibBlock`].
pub const VIB_BLOCK_MAX: usize = 512;
/// Most tones per [`VibEstimate`]: `vibro_dsp::MAX_TONES`, so every estimate fits.
pub const MAX_TONES: usize = 16;
/// Most PSD bands per [`VibEstimate`]: `vibro_dsp::MAX_BANDS`.
pub const MAX_BANDS: usize = 16;
/// Most bytes of text per [`LogLine`] (a longer line is cut at a character boundary).
pub const LOG_TEXT_MAX: usize = 488;

/// Errors of the message contracts. Messages carry the offending value.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Error {
    /// A service-name prefix broke a rule of [`ServiceNames::new`].
    #[error("service-name prefix {prefix:?}: {rule}")]
    InvalidPrefix { prefix: String, rule: String },
    /// A count field exceeds its array's capacity.
    #[error("{field} = {count}: must be at most {max}")]
    CountOutOfRange {
        field: &'static str,
        count: u32,
        max: usize,
    },
    /// A `u8` code field holds no known value.
    #[error("{field} = {value}: not a known code ({known})")]
    UnknownCode {
        field: &'static str,
        value: u8,
        known: String,
    },
    /// A text field's used bytes are not UTF-8.
    #[error("{field}: not UTF-8 (valid up to byte {valid_up_to})")]
    NotUtf8 {
        field: &'static str,
        valid_up_to: usize,
    },
    /// iceoryx2 rejected a service name (cannot happen for a validated prefix).
    #[error("service name {name:?} rejected by iceoryx2: {reason}")]
    ServiceName { name: String, reason: String },
}

/// `Result` with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

#[cfg(test)]
mod tests {
    use super::*;
    use iceoryx2::prelude::ZeroCopySend;

    fn iceoryx_type_name<T: ZeroCopySend>() -> &'static str {
        // SAFETY: `type_name` is unsafe only because implementors must keep it unique
        // per layout; reading it is harmless.
        unsafe { <T as ZeroCopySend>::type_name() }
    }

    #[test]
    fn iceoryx2_sees_the_versioned_type_names() {
        let expected = [
            (
                iceoryx_type_name::<AccelBlock>(),
                "vibrocomp::AccelBlock::v5",
            ),
            (iceoryx_type_name::<VibBlock>(), "vibrocomp::VibBlock::v5"),
            (
                iceoryx_type_name::<VibEstimate>(),
                "vibrocomp::VibEstimate::v5",
            ),
            (
                iceoryx_type_name::<CompensatedBlock>(),
                "vibrocomp::CompensatedBlock::v5",
            ),
            (
                iceoryx_type_name::<TruthBlock>(),
                "vibrocomp::TruthBlock::v5",
            ),
            (iceoryx_type_name::<Heartbeat>(), "vibrocomp::Heartbeat::v5"),
            (iceoryx_type_name::<LogLine>(), "vibrocomp::LogLine::v5"),
        ];
        for (seen, want) in expected {
            assert_eq!(seen, want);
        }
        for kind in MessageKind::ALL {
            assert_eq!(
                kind.type_name(),
                format!("vibrocomp::{}::v{SCHEMA_VERSION}", kind.name())
            );
        }
    }

    #[test]
    fn zeroed_messages_are_all_zero_bytes_and_the_default() {
        fn check<T: WireMessage + Default + PartialEq>(zeroed: T) {
            assert!(zeroed.bytes().iter().all(|&b| b == 0));
            assert_eq!(zeroed.bytes().len(), T::KIND.size_bytes());
            assert_eq!(T::default(), zeroed);
        }
        check(AccelBlock::ZEROED);
        check(VibBlock::ZEROED);
        check(VibEstimate::ZEROED);
        check(CompensatedBlock::ZEROED);
        check(TruthBlock::ZEROED);
        check(Heartbeat::ZEROED);
        check(LogLine::ZEROED);
    }

    #[test]
    fn as_bytes_shows_fields_at_their_offsets_in_native_order() {
        let mut b = AccelBlock::ZEROED;
        b.seq = 0x0102_0304_0506_0708;
        b.output_v[1][2] = -0.0;
        b.count = 7;
        let bytes = b.as_bytes();
        assert_eq!(bytes[0..8], 0x0102_0304_0506_0708u64.to_ne_bytes());
        // output_v starts at 40; [1][2] is element 1 * 3 + 2 = 5.
        let at = 40 + 5 * 8;
        assert_eq!(bytes[at..at + 8], (-0.0f64).to_ne_bytes());
        let count_at = AccelBlock::FIELDS
            .iter()
            .find(|f| f.name == "count")
            .unwrap()
            .offset_bytes;
        assert_eq!(bytes[count_at..count_at + 4], 7u32.to_ne_bytes());
    }

    #[test]
    fn field_tables_cover_each_struct_exactly() {
        for kind in MessageKind::ALL {
            let mut next = 0;
            for f in kind.fields() {
                assert_eq!(f.offset_bytes, next, "{kind}.{} is not contiguous", f.name);
                next += f.size_bytes;
            }
            assert_eq!(next, kind.size_bytes(), "{kind}");
            assert_eq!(kind.size_bytes() % kind.align_bytes(), 0);
            assert_eq!(kind.align_bytes(), 8, "{kind}");
        }
        let output = AccelBlock::FIELDS
            .iter()
            .find(|f| f.name == "output_v")
            .unwrap();
        assert_eq!(output.rust_type(), "[[f64; 3]; 32]");
        assert_eq!(output.c_type(), "double[32][3]");
        assert_eq!(output.size_bytes, 32 * 3 * 8);
    }

    #[test]
    fn counts_beyond_capacity_are_rejected_with_field_and_value() {
        let mut b = VibBlock::ZEROED;
        b.count = VIB_BLOCK_MAX as u32;
        assert_eq!(b.validate(), Ok(()));
        assert_eq!(b.samples_v().len(), VIB_BLOCK_MAX);
        b.count = VIB_BLOCK_MAX as u32 + 1;
        assert_eq!(b.samples_v().len(), VIB_BLOCK_MAX);
        let e = b.validate().unwrap_err();
        assert_eq!(e.to_string(), "VibBlock.count = 513: must be at most 512");

        let mut est = VibEstimate::ZEROED;
        est.tone_count = 16;
        est.band_count = 17;
        assert_eq!(
            est.validate().unwrap_err().to_string(),
            "VibEstimate.band_count = 17: must be at most 16"
        );
        let mut a = AccelBlock::ZEROED;
        a.count = u32::MAX;
        assert!(matches!(
            a.validate(),
            Err(Error::CountOutOfRange {
                count: u32::MAX,
                max: 32,
                ..
            })
        ));
        let mut c = CompensatedBlock::ZEROED;
        c.count = 33;
        assert!(c.validate().is_err());
        let mut t = TruthBlock::ZEROED;
        t.count = 32;
        assert!(t.validate().is_ok());
    }

    #[test]
    fn codes_convert_both_ways_and_unknown_codes_are_named() {
        for &m in CompensationMode::ALL {
            assert_eq!(CompensationMode::try_from(m.code()), Ok(m));
        }
        assert_eq!(CompensationMode::Exact.code(), 3);
        assert_eq!(CompensationMode::AsPublished.as_str(), "as-published");
        assert_eq!(ServiceId::try_from(4), Ok(ServiceId::Compensator));
        assert_eq!(ServiceState::try_from(2), Ok(ServiceState::Running));
        let e = CompensationMode::try_from(0).unwrap_err();
        assert_eq!(
            e.to_string(),
            "CompensatedBlock.mode = 0: not a known code (1 = as-published, 2 = paper, 3 = exact)"
        );
        assert!(ServiceId::try_from(7)
            .unwrap_err()
            .to_string()
            .starts_with("Heartbeat.service = 7"));
    }

    #[test]
    fn flag_sets_are_disjoint_bits() {
        assert_eq!(
            compensation_flags::ALL.count_ones(),
            13,
            "thirteen distinct compensation flags"
        );
        assert_eq!(compensation_flags::ALL, 0x1fff, "bits 0..12, no hole");
        assert_eq!(estimate_flags::ALL.count_ones(), 9);
        assert_eq!(accel_flags::ALL, 0b11);
        assert_eq!(vib_flags::ALL, 0b111);
        assert_eq!(truth_flags::ALL, 0b111);
    }
}
