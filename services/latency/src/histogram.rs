//! The latency histograms: each hop's percentiles ([`HopUs`]) and the soak's end to
//! end per accelerometer block ([`EndToEndHistogram`]).

use anyhow::Context;
use hdrhistogram::Histogram;
use serde::Serialize;
use vibro_msgs::CompensatedBlock;

/// Percentiles of one hop, microseconds.
#[derive(Debug, Clone, Default, Serialize)]
pub struct HopUs {
    pub count: u64,
    pub p50_us: f64,
    pub p90_us: f64,
    pub p99_us: f64,
    pub p999_us: f64,
    pub max_us: f64,
}

pub(crate) fn hop(h: &Histogram<u64>) -> HopUs {
    if h.is_empty() {
        return HopUs::default();
    }
    let q = |x: f64| h.value_at_quantile(x) as f64 * 1e-3;
    HopUs {
        count: h.len(),
        p50_us: q(0.5),
        p90_us: q(0.9),
        p99_us: q(0.99),
        p999_us: q(0.999),
        max_us: h.max() as f64 * 1e-3,
    }
}

/// The four stamps of one compensated block.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Stamps {
    pub(crate) input_seq: u64,
    pub(crate) t0_ns: u64,
    pub(crate) input_publish_ns: u64,
    pub(crate) recv_ns: u64,
    pub(crate) publish_ns: u64,
    pub(crate) sub_recv_ns: u64,
    pub(crate) count: u32,
    /// The compensated block's flags (`compensation_flags`).
    pub(crate) flags: u32,
    /// The newest vibration block the rig published before this block's publish
    /// (`RigStream::stamp_vib`; 0 until stamped, or when none was).
    pub(crate) last_vib_publish_ns: u64,
}

impl Stamps {
    /// The stamps `b` carries, received by the rig at `sub_recv_ns`.
    pub(crate) fn of(b: &CompensatedBlock, sub_recv_ns: u64) -> Self {
        Self {
            input_seq: b.input_seq,
            t0_ns: b.t0_ns,
            input_publish_ns: b.input_publish_ns,
            recv_ns: b.recv_ns,
            publish_ns: b.publish_ns,
            sub_recv_ns,
            count: b.count,
            flags: b.flags,
            last_vib_publish_ns: 0,
        }
    }
}

pub(crate) struct Histograms {
    pub(crate) rig_to_service: Histogram<u64>,
    pub(crate) processing: Histogram<u64>,
    pub(crate) service_to_subscriber: Histogram<u64>,
    pub(crate) end_to_end: Histogram<u64>,
    /// Rig publish of the accelerometer block -> compensator publish: what the
    /// pipeline adds before the last transport hop (with the waveform stage, the wait
    /// for the samples covering the block).
    pub(crate) input_to_publish: Histogram<u64>,
    /// The last input the block needed, published by the rig -> compensator publish:
    /// for a block the waveform stage made (`WAVEFORM`), the later of its accelerometer
    /// block and the newest vibration block before its publish (the one whose samples
    /// released it); for the others, its accelerometer block. One transport hop and
    /// the compensator's work, without the wait.
    pub(crate) last_input_to_publish: Histogram<u64>,
    /// Compensated blocks recorded, and those the waveform stage made.
    pub(crate) blocks: u64,
    pub(crate) waveform_blocks: u64,
}

impl Histograms {
    pub(crate) fn new() -> anyhow::Result<Self> {
        let h = || Histogram::new_with_bounds(1, 60_000_000_000, 3).context("histogram");
        Ok(Self {
            rig_to_service: h()?,
            processing: h()?,
            service_to_subscriber: h()?,
            end_to_end: h()?,
            input_to_publish: h()?,
            last_input_to_publish: h()?,
            blocks: 0,
            waveform_blocks: 0,
        })
    }

    pub(crate) fn record(&mut self, s: &Stamps) {
        let d = |a: u64, b: u64| a.saturating_sub(b).max(1);
        let _ = self.rig_to_service.record(d(s.recv_ns, s.input_publish_ns));
        let _ = self.processing.record(d(s.publish_ns, s.recv_ns));
        let _ = self
            .service_to_subscriber
            .record(d(s.sub_recv_ns, s.publish_ns));
        let _ = self.end_to_end.record(d(s.sub_recv_ns, s.input_publish_ns));
        let _ = self
            .input_to_publish
            .record(d(s.publish_ns, s.input_publish_ns));
        let waveform = s.flags & vibro_msgs::compensation_flags::WAVEFORM != 0;
        let last_input_ns = if waveform {
            s.input_publish_ns.max(s.last_vib_publish_ns)
        } else {
            s.input_publish_ns
        };
        let _ = self
            .last_input_to_publish
            .record(d(s.publish_ns, last_input_ns));
        self.blocks += 1;
        self.waveform_blocks += u64::from(waveform);
    }
}

/// One line of the percentile table.
#[derive(Debug, Clone, Serialize)]
pub struct PercentileRow {
    pub percentile: f64,
    pub value_us: f64,
    /// Blocks whose end-to-end latency is at or below `value_us` (counted exactly).
    pub blocks_at_or_below: u64,
}

/// One bucket: blocks with `lower_us < latency <= upper_us` (`upper_us` null: above
/// the last bound).
#[derive(Debug, Clone, Serialize)]
pub struct BucketRow {
    pub lower_us: f64,
    pub upper_us: Option<f64>,
    pub blocks: u64,
}

/// The end-to-end latency per accelerometer block after the warm-up.
#[derive(Debug, Clone, Serialize)]
pub struct EndToEndHistogram {
    pub count: u64,
    pub percentiles: Vec<PercentileRow>,
    pub buckets: Vec<BucketRow>,
}

const BUCKET_BOUNDS_US: [f64; 16] = [
    100.0, 150.0, 200.0, 250.0, 300.0, 400.0, 500.0, 750.0, 1000.0, 1250.0, 1500.0, 2000.0, 3000.0,
    5000.0, 10000.0, 50000.0,
];

/// The end-to-end latency of the blocks whose first sample ends at or after
/// `warmup_s` of data time.
pub(crate) fn end_to_end_histogram(
    warmup_s: f64,
    stamps: &[Stamps],
) -> anyhow::Result<EndToEndHistogram> {
    let warmup_ns = (warmup_s * 1e9) as u64;
    // The same values as the hop table's end to end (`Histograms::record`).
    let values_ns: Vec<u64> = stamps
        .iter()
        .filter(|s| s.t0_ns >= warmup_ns)
        .map(|s| s.sub_recv_ns.saturating_sub(s.input_publish_ns).max(1))
        .collect();
    let mut h = Histogram::<u64>::new_with_bounds(1, 60_000_000_000, 3).context("histogram")?;
    for &v in &values_ns {
        let _ = h.record(v);
    }
    let percentiles = if h.is_empty() {
        Vec::new()
    } else {
        [
            50.0, 75.0, 90.0, 95.0, 99.0, 99.5, 99.9, 99.95, 99.99, 100.0,
        ]
        .iter()
        .map(|&p| {
            let v = if p >= 100.0 {
                h.max()
            } else {
                h.value_at_quantile(p / 100.0)
            };
            PercentileRow {
                percentile: p,
                value_us: v as f64 * 1e-3,
                blocks_at_or_below: values_ns.iter().filter(|&&x| x <= v).count() as u64,
            }
        })
        .collect()
    };
    let mut lower_us = 0.0;
    let mut buckets = Vec::with_capacity(BUCKET_BOUNDS_US.len() + 1);
    for upper in BUCKET_BOUNDS_US.iter().map(|&u| Some(u)).chain([None]) {
        let (lo_ns, hi_ns) = (lower_us * 1e3, upper.map_or(f64::INFINITY, |u| u * 1e3));
        let blocks = values_ns
            .iter()
            .filter(|&&x| (x as f64) > lo_ns && (x as f64) <= hi_ns)
            .count() as u64;
        buckets.push(BucketRow {
            lower_us,
            upper_us: upper,
            blocks,
        });
        lower_us = upper.unwrap_or(lower_us);
    }
    Ok(EndToEndHistogram {
        count: values_ns.len() as u64,
        percentiles,
        buckets,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64, rel: f64) -> bool {
        (a - b).abs() <= rel * b.abs()
    }

    fn stamps_e2e_us(values_us: &[f64], t0_ns: u64) -> Vec<Stamps> {
        values_us
            .iter()
            .map(|&v| Stamps {
                t0_ns,
                input_publish_ns: 1_000_000,
                sub_recv_ns: 1_000_000 + (v * 1e3) as u64,
                ..Stamps::default()
            })
            .collect()
    }

    #[test]
    fn hop_percentiles_of_one_to_a_thousand_ns() {
        // Values below 2048 are exact at 3 significant digits; the q-quantile of
        // 1..=1000 is the ceil(1000 q)-th value.
        let mut h = Histograms::new().unwrap().end_to_end;
        for v in 1..=1000u64 {
            h.record(v).unwrap();
        }
        let p = hop(&h);
        assert_eq!(p.count, 1000);
        for (got, want_us) in [
            (p.p50_us, 0.5),
            (p.p90_us, 0.9),
            (p.p99_us, 0.99),
            (p.p999_us, 0.999),
            (p.max_us, 1.0),
        ] {
            assert!((got - want_us).abs() <= 1e-3 + 1e-12, "{got} vs {want_us}");
        }
    }

    #[test]
    fn an_empty_hop_is_all_zero() {
        let h = Histograms::new().unwrap();
        let p = hop(&h.processing);
        assert_eq!(p.count, 0);
        assert_eq!(p.max_us, 0.0);
    }

    #[test]
    fn a_waveform_block_is_timed_from_the_vibration_block_that_released_it() {
        let mut h = Histograms::new().unwrap();
        let waveform = vibro_msgs::compensation_flags::WAVEFORM;
        // Accelerometer block published at 1 ms, the covering vibration block at
        // 21 ms, the compensated block at 21.1 ms.
        let s = Stamps {
            input_publish_ns: 1_000_000,
            recv_ns: 1_050_000,
            publish_ns: 21_100_000,
            sub_recv_ns: 21_150_000,
            flags: waveform,
            last_vib_publish_ns: 21_000_000,
            ..Stamps::default()
        };
        h.record(&s);
        // The estimate stage's block is timed from its accelerometer block, whatever
        // vibration block came before its publish.
        h.record(&Stamps { flags: 0, ..s });
        // A waveform block whose samples were there before it: from its own block.
        h.record(&Stamps {
            last_vib_publish_ns: 500_000,
            ..s
        });
        let within = |v: u64, want: u64| v.abs_diff(want) <= want / 500;
        assert!(within(h.input_to_publish.max(), 20_100_000));
        assert!(within(h.last_input_to_publish.min(), 100_000));
        assert!(within(h.last_input_to_publish.max(), 20_100_000));
        assert_eq!(h.last_input_to_publish.count_between(0, 200_000), 1);
        assert_eq!((h.blocks, h.waveform_blocks), (3, 2));
    }

    #[test]
    fn a_block_records_each_hop_from_its_stamps() {
        let mut h = Histograms::new().unwrap();
        h.record(&Stamps {
            input_publish_ns: 1_000,
            recv_ns: 1_500,
            publish_ns: 1_600,
            sub_recv_ns: 2_100,
            ..Stamps::default()
        });
        // A clock step backwards records the 1 ns floor, not a wrapped u64.
        h.record(&Stamps {
            input_publish_ns: 5_000,
            recv_ns: 4_000,
            publish_ns: 4_000,
            sub_recv_ns: 4_000,
            ..Stamps::default()
        });
        assert_eq!(h.rig_to_service.max(), 500);
        assert_eq!(h.processing.max(), 100);
        assert_eq!(h.service_to_subscriber.max(), 500);
        assert_eq!(h.end_to_end.max(), 1_100);
        assert_eq!(h.input_to_publish.max(), 600);
        assert_eq!((h.blocks, h.waveform_blocks), (2, 0));
        for x in [&h.rig_to_service, &h.end_to_end] {
            assert_eq!(x.min(), 1);
            assert_eq!(x.len(), 2);
        }
    }

    #[test]
    fn end_to_end_buckets_and_percentiles_count_the_blocks_after_the_warmup() {
        // 100 us sits in the first bucket (upper bounds inclusive); 60 ms is above the
        // last bound; the block before the warm-up is left out.
        let mut stamps = stamps_e2e_us(&[50.0, 100.0, 120.0, 150.0, 60_000.0], 2_000_000_000);
        stamps.extend(stamps_e2e_us(&[75.0], 999_999_999));
        let h = end_to_end_histogram(1.0, &stamps).unwrap();
        assert_eq!(h.count, 5);
        assert_eq!(h.buckets.len(), BUCKET_BOUNDS_US.len() + 1);
        let nonzero: Vec<(f64, Option<f64>, u64)> = h
            .buckets
            .iter()
            .filter(|b| b.blocks > 0)
            .map(|b| (b.lower_us, b.upper_us, b.blocks))
            .collect();
        assert_eq!(
            nonzero,
            [
                (0.0, Some(100.0), 2),
                (100.0, Some(150.0), 2),
                (50_000.0, None, 1)
            ]
        );
        assert_eq!(h.buckets.iter().map(|b| b.blocks).sum::<u64>(), 5);
        let row = |p: f64| h.percentiles.iter().find(|r| r.percentile == p).unwrap();
        // p50: the 3rd of 5 values, 120 us (within the histogram's 0.1 %).
        assert!(close(row(50.0).value_us, 120.0, 1e-3), "{:?}", row(50.0));
        assert_eq!(row(50.0).blocks_at_or_below, 3);
        assert!(close(row(100.0).value_us, 60_000.0, 1e-3));
        assert_eq!(row(100.0).blocks_at_or_below, 5);
        assert_eq!(h.percentiles.len(), 10);
    }

    #[test]
    fn no_blocks_give_empty_percentiles_and_zero_buckets() {
        let h = end_to_end_histogram(0.0, &[]).unwrap();
        assert_eq!(h.count, 0);
        assert!(h.percentiles.is_empty());
        assert!(h.buckets.iter().all(|b| b.blocks == 0));
        assert_eq!(h.buckets.last().map(|b| b.upper_us), Some(None));
    }
}
