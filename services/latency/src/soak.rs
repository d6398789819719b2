//! The soak: the vibrocomp pipeline alone, every accelerometer block's answer checked
//! ([`AccelCheck`]), the services' counters and memory, the end-to-end histogram, and
//! p99.9 against one accelerometer sample period, optionally beside a background load.

use serde::Serialize;
use std::path::Path;

use crate::cpu::MachineCpu;
use crate::histogram::{end_to_end_histogram, EndToEndHistogram, Stamps};
use crate::load::{start_load, stop_load, LoadReport};
use crate::memory::{memory_summary, MemorySummary, MEMORY_FLAT_BOUND_KIB};
use crate::pipelines::{losses, run_vibrocomp, PipelineRun};
use crate::Options;

/// Every accelerometer block answered once, in order: from the compensated blocks'
/// `input_seq`.
#[derive(Debug, Clone, Serialize)]
pub struct AccelCheck {
    pub sent: u64,
    /// Distinct blocks `0..sent` answered.
    pub answered: u64,
    /// Blocks never answered.
    pub missing: u64,
    /// Blocks answered more than once (extra answers).
    pub duplicates: u64,
    /// Answers whose `input_seq` is not the previous one's plus 1.
    pub out_of_order: u64,
    /// Answers to blocks the rig never sent.
    pub unknown: u64,
    pub continuous: bool,
}

pub(crate) fn accel_check(sent: u64, stamps: &[Stamps]) -> AccelCheck {
    let mut seen = vec![0u32; sent as usize];
    let (mut unknown, mut out_of_order) = (0u64, 0u64);
    let mut prev: Option<u64> = None;
    for s in stamps {
        match seen.get_mut(s.input_seq as usize) {
            Some(n) => *n += 1,
            None => unknown += 1,
        }
        if prev.is_some_and(|p| s.input_seq != p + 1) || (prev.is_none() && s.input_seq != 0) {
            out_of_order += 1;
        }
        prev = Some(s.input_seq);
    }
    let answered = seen.iter().filter(|&&n| n > 0).count() as u64;
    let duplicates: u64 = seen.iter().map(|&n| u64::from(n.saturating_sub(1))).sum();
    let missing = sent - answered;
    AccelCheck {
        sent,
        answered,
        missing,
        duplicates,
        out_of_order,
        unknown,
        continuous: missing == 0 && duplicates == 0 && out_of_order == 0 && unknown == 0,
    }
}

/// The services' own counters at exit.
#[derive(Debug, Clone, Serialize)]
pub struct ServiceCounts {
    pub compensator_accel_received: u64,
    /// Lost messages and samples on `{prefix}accel`, plus outputs not delivered.
    pub compensator_lost: u64,
    pub estimator_vib_received: u64,
    pub estimator_lost: u64,
    pub estimator_rate_mismatches: u64,
    pub estimates_published: u64,
    pub estimates_flagged: u64,
    /// From the block that completes a window to its estimate: the estimator's own
    /// `latency` (count, p50_ns, p99_ns, max_ns).
    pub estimator_window: serde_json::Value,
}

/// The soak's report (`vibrocomp latency --soak`).
#[derive(Debug, Clone, Serialize)]
pub struct SoakReport {
    pub soak: bool,
    pub mode: String,
    /// `SCHED_FIFO` priority of the services' hot loops and the rig's receiver.
    pub realtime_priority: Option<u8>,
    pub prefix: String,
    pub duration_s: f64,
    pub warmup_s: f64,
    pub rate_hz: f64,
    pub block_samples: u32,
    pub vib_rate_hz: f64,
    pub vib_block_samples: u32,
    /// The estimator ran with `sample_rate_hz = vib_rate_hz` (a private configuration
    /// when the default's rate differs).
    pub estimator_config: String,
    pub run: PipelineRun,
    pub accel: AccelCheck,
    pub services: ServiceCounts,
    /// Every vibration block the rig sent was taken by the estimator.
    pub vib_blocks_taken: bool,
    /// Accelerometer blocks not answered, plus the services' own losses.
    pub lost: u64,
    pub memory_flat_bound_kib: u64,
    pub memory: Vec<MemorySummary>,
    pub load: Option<LoadReport>,
    /// All cores' busy time over the soak (from `/proc/stat`), percent of all of them:
    /// ours and whatever else the machine ran.
    pub machine_busy_percent: f64,
    pub cores: usize,
    pub end_to_end_histogram: EndToEndHistogram,
    /// One accelerometer sample period, us.
    pub target_p999_us: f64,
    pub p999_met: bool,
}

pub(crate) fn run_soak(
    opts: &Options,
    k1: [f64; 3],
    log: &Path,
    prefix: &str,
    (estimator_config, compensator_config): (Option<&Path>, Option<&Path>),
) -> anyhow::Result<SoakReport> {
    let machine = MachineCpu::now();
    // The load first, so that the services start and run beside it.
    let load = match &opts.load {
        Some(l) => Some(start_load(&l.input, l.jobs, log)?),
        None => None,
    };
    let result = run_vibrocomp(
        opts,
        k1,
        log,
        prefix,
        (estimator_config, compensator_config),
    );
    let machine_busy_percent = machine.busy_percent_since();
    // Stopped whatever happened; the pipeline's error, if any, comes first.
    let load = match (load, &opts.load) {
        (Some(child), Some(l)) => Some(stop_load(child, &l.input, l.jobs)),
        _ => None,
    };
    let v = result?;
    let load = load.transpose()?;
    let g = |s: &serde_json::Value, a: &str, b: &str| s[a][b].as_u64().unwrap_or(0);
    let services = ServiceCounts {
        compensator_accel_received: g(&v.compensator, "accel", "received"),
        compensator_lost: losses(&v.compensator, "accel"),
        estimator_vib_received: g(&v.estimator, "vib", "received"),
        estimator_lost: losses(&v.estimator, "vib"),
        estimator_rate_mismatches: v.estimator["rate_mismatches"].as_u64().unwrap_or(0),
        estimates_published: v.estimator["estimates_published"].as_u64().unwrap_or(0),
        estimates_flagged: v.estimator["estimates_flagged"].as_u64().unwrap_or(0),
        estimator_window: v.estimator["latency"].clone(),
    };
    let accel = accel_check(v.run.accel_blocks_sent, &v.stamps);
    let target_p999_us = 1e6 / opts.rate_hz;
    Ok(SoakReport {
        soak: true,
        mode: opts.mode.as_str().to_string(),
        realtime_priority: opts.realtime_priority,
        prefix: prefix.to_string(),
        duration_s: opts.duration_s,
        warmup_s: opts.warmup_s,
        rate_hz: opts.rate_hz,
        block_samples: opts.block_samples,
        vib_rate_hz: opts.vib_rate_hz,
        vib_block_samples: opts.vib_block_samples,
        estimator_config: estimator_config
            .map_or("default".to_string(), |p| p.display().to_string()),
        vib_blocks_taken: services.estimator_vib_received == v.run.vib_blocks_sent
            && services.estimator_rate_mismatches == 0,
        lost: accel.missing + services.compensator_lost + services.estimator_lost,
        accel,
        services,
        memory_flat_bound_kib: MEMORY_FLAT_BOUND_KIB,
        memory: v
            .memory
            .iter()
            .map(|s| memory_summary(s, opts.warmup_s))
            .collect(),
        load,
        machine_busy_percent,
        cores: std::thread::available_parallelism().map_or(0, |n| n.get()),
        end_to_end_histogram: end_to_end_histogram(opts.warmup_s, &v.stamps)?,
        target_p999_us,
        p999_met: v.run.end_to_end.count > 0 && v.run.end_to_end.p999_us < target_p999_us,
        run: v.run,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn answers(input_seq: &[u64]) -> Vec<Stamps> {
        input_seq
            .iter()
            .map(|&input_seq| Stamps {
                input_seq,
                ..Stamps::default()
            })
            .collect()
    }

    #[test]
    fn every_block_answered_once_in_order_is_continuous() {
        let a = accel_check(3, &answers(&[0, 1, 2]));
        assert_eq!((a.sent, a.answered, a.missing), (3, 3, 0));
        assert_eq!((a.duplicates, a.out_of_order, a.unknown), (0, 0, 0));
        assert!(a.continuous);
    }

    #[test]
    fn gaps_repeats_and_strangers_are_each_counted() {
        // Sent 0..5; answered 0, 1, 1, 3 and 7 (never sent): 2 and 4 missing, one
        // duplicate, and 1 -> 1, 1 -> 3, 3 -> 7 out of order.
        let a = accel_check(5, &answers(&[0, 1, 1, 3, 7]));
        assert_eq!((a.answered, a.missing, a.duplicates), (3, 2, 1));
        assert_eq!((a.out_of_order, a.unknown), (3, 1));
        assert!(!a.continuous);
    }

    #[test]
    fn a_first_answer_other_than_block_zero_is_out_of_order() {
        let a = accel_check(2, &answers(&[1]));
        assert_eq!((a.answered, a.missing, a.out_of_order), (1, 1, 1));
        let none = accel_check(0, &[]);
        assert!(none.continuous);
    }
}
