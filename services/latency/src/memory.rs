//! The services' resident memory over a soak: sampled once a second from
//! `/proc/PID/status` ([`MemorySampler`]) and summarized ([`memory_summary`]).

use serde::Serialize;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A process's resident memory, sampled every second.
#[derive(Debug, Clone, Default)]
pub(crate) struct MemorySeries {
    pub(crate) process: String,
    /// Seconds since the rig started sending.
    pub(crate) t_s: Vec<f64>,
    /// `VmRSS` and `RssAnon` of `/proc/PID/status`, KiB.
    pub(crate) rss_kib: Vec<u64>,
    pub(crate) anon_kib: Vec<u64>,
}

/// `key` (e.g. `VmRSS`) of `/proc/PID/status`, KiB.
fn status_kib(status: &str, key: &str) -> Option<u64> {
    let line = status
        .lines()
        .find(|l| l.strip_prefix(key).is_some_and(|r| r.starts_with(':')))?;
    line.get(key.len() + 1..)?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// Samples the processes' memory once a second on a thread of its own, until
/// [`MemorySampler::finish`].
pub(crate) struct MemorySampler {
    stop: Arc<AtomicBool>,
    thread: std::thread::JoinHandle<Vec<MemorySeries>>,
}

impl MemorySampler {
    pub(crate) fn start(pids: &[(&str, u32)]) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let pids: Vec<(String, u32)> = pids.iter().map(|&(n, p)| (n.to_string(), p)).collect();
        let flag = Arc::clone(&stop);
        let thread = std::thread::spawn(move || {
            let mut series: Vec<MemorySeries> = pids
                .iter()
                .map(|(n, _)| MemorySeries {
                    process: n.clone(),
                    t_s: Vec::new(),
                    rss_kib: Vec::new(),
                    anon_kib: Vec::new(),
                })
                .collect();
            let start = Instant::now();
            let mut k = 0u32;
            'sampling: loop {
                let t = start.elapsed().as_secs_f64();
                for ((_, pid), s) in pids.iter().zip(&mut series) {
                    let Ok(status) = std::fs::read_to_string(format!("/proc/{pid}/status")) else {
                        continue;
                    };
                    if let (Some(rss), Some(anon)) =
                        (status_kib(&status, "VmRSS"), status_kib(&status, "RssAnon"))
                    {
                        s.t_s.push(t);
                        s.rss_kib.push(rss);
                        s.anon_kib.push(anon);
                    }
                }
                k += 1;
                let next = Duration::from_secs(u64::from(k));
                loop {
                    if flag.load(Ordering::Acquire) {
                        break 'sampling;
                    }
                    let now = start.elapsed();
                    if now >= next {
                        break;
                    }
                    std::thread::sleep((next - now).min(Duration::from_millis(50)));
                }
            }
            series
        });
        Self { stop, thread }
    }

    pub(crate) fn finish(self) -> Vec<MemorySeries> {
        self.stop.store(true, Ordering::Release);
        self.thread.join().unwrap_or_default()
    }
}

/// "Flat": after the warm-up, the anonymous resident memory (`RssAnon`) never rises
/// more than this above its first sample after the warm-up.
pub const MEMORY_FLAT_BOUND_KIB: u64 = 1024;

/// One process's memory over the soak, KiB.
#[derive(Debug, Clone, Serialize)]
pub struct MemorySummary {
    pub process: String,
    pub samples: usize,
    pub first_kib: u64,
    pub last_kib: u64,
    pub max_kib: u64,
    /// The first sample at or after `--warmup-s`.
    pub after_warmup_kib: u64,
    /// Highest sample after the warm-up minus `after_warmup_kib`.
    pub growth_after_warmup_kib: u64,
    /// Least-squares slope of the samples after the warm-up, KiB per minute.
    pub slope_kib_per_min: f64,
    pub anon_first_kib: u64,
    pub anon_last_kib: u64,
    /// `RssAnon` (the heap and stacks: what a leak grows), the same way as
    /// `growth_after_warmup_kib`. `VmRSS` also counts the shared-memory pages of the
    /// iceoryx2 segments as the process first touches them, which stops at the
    /// segments' size.
    pub anon_growth_after_warmup_kib: u64,
    /// `VmRSS`: the highest sample of the second half of the soak minus the sample at
    /// its middle. A leak keeps growing there; a one-time step while the services
    /// settle (a thread's first allocation, a table built once) does not.
    pub second_half_growth_kib: u64,
    /// `RssAnon` grew at most [`MEMORY_FLAT_BOUND_KIB`] after the warm-up.
    pub flat: bool,
    /// `VmRSS`, one sample a second.
    pub series_kib: Vec<u64>,
}

pub(crate) fn memory_summary(s: &MemorySeries, warmup_s: f64) -> MemorySummary {
    let first = s.rss_kib.first().copied().unwrap_or(0);
    let last = s.rss_kib.last().copied().unwrap_or(0);
    // Samples at or after the warm-up; all of them in a run too short to have any.
    let from = s.t_s.iter().position(|&t| t >= warmup_s).unwrap_or(0);
    let (t, m) = (&s.t_s[from..], &s.rss_kib[from..]);
    let base = m.first().copied().unwrap_or(0);
    let growth = m.iter().max().copied().unwrap_or(0).saturating_sub(base);
    let anon = &s.anon_kib[from.min(s.anon_kib.len())..];
    let anon_growth = anon
        .iter()
        .max()
        .copied()
        .unwrap_or(0)
        .saturating_sub(anon.first().copied().unwrap_or(0));
    let n = t.len() as f64;
    let slope = if t.len() >= 2 {
        let (tm, mm) = (
            t.iter().sum::<f64>() / n,
            m.iter().map(|&x| x as f64).sum::<f64>() / n,
        );
        let sxy: f64 = t
            .iter()
            .zip(m)
            .map(|(&t, &x)| (t - tm) * (x as f64 - mm))
            .sum();
        let sxx: f64 = t.iter().map(|&t| (t - tm) * (t - tm)).sum();
        if sxx > 0.0 {
            60.0 * sxy / sxx
        } else {
            0.0
        }
    } else {
        0.0
    };
    MemorySummary {
        process: s.process.clone(),
        samples: s.rss_kib.len(),
        first_kib: first,
        last_kib: last,
        max_kib: s.rss_kib.iter().max().copied().unwrap_or(0),
        after_warmup_kib: base,
        growth_after_warmup_kib: growth,
        slope_kib_per_min: slope,
        anon_first_kib: s.anon_kib.first().copied().unwrap_or(0),
        anon_last_kib: s.anon_kib.last().copied().unwrap_or(0),
        anon_growth_after_warmup_kib: anon_growth,
        second_half_growth_kib: {
            let half = &s.rss_kib[s.rss_kib.len() / 2..];
            let mid = half.first().copied().unwrap_or(0);
            half.iter().max().copied().unwrap_or(0).saturating_sub(mid)
        },
        flat: !anon.is_empty() && anon_growth <= MEMORY_FLAT_BOUND_KIB,
        series_kib: s.rss_kib.clone(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn series(rss_kib: &[u64], anon_kib: &[u64]) -> MemorySeries {
        MemorySeries {
            process: "estimator".into(),
            t_s: (0..rss_kib.len()).map(|k| k as f64).collect(),
            rss_kib: rss_kib.to_vec(),
            anon_kib: anon_kib.to_vec(),
        }
    }

    #[test]
    fn status_kib_reads_the_named_key_only() {
        let status =
            "Name:\tvibrocomp\nVmRSS:\t   12345 kB\nRssAnon:\t     678 kB\nRssFile:\t 9 kB\n";
        assert_eq!(status_kib(status, "VmRSS"), Some(12345));
        assert_eq!(status_kib(status, "RssAnon"), Some(678));
        // A key is a whole name before the colon, not a prefix of another.
        assert_eq!(status_kib(status, "Rss"), None);
        assert_eq!(status_kib(status, "VmHWM"), None);
        assert_eq!(status_kib("VmRSS:\n", "VmRSS"), None);
        assert_eq!(status_kib("VmRSS: lots kB\n", "VmRSS"), None);
    }

    #[test]
    fn a_growing_series_after_the_warmup() {
        // One sample a second; warm-up 1.5 s: the samples from t = 2 s, 210..240 KiB,
        // rise 10 KiB/s = 600 KiB/min. RssAnon after it: 60, 61, 60, 62 (growth 2).
        let s = series(&[100, 200, 210, 220, 230, 240], &[50, 60, 60, 61, 60, 62]);
        let m = memory_summary(&s, 1.5);
        assert_eq!(m.samples, 6);
        assert_eq!((m.first_kib, m.last_kib, m.max_kib), (100, 240, 240));
        assert_eq!(m.after_warmup_kib, 210);
        assert_eq!(m.growth_after_warmup_kib, 30);
        assert!(
            (m.slope_kib_per_min - 600.0).abs() < 1e-9,
            "{}",
            m.slope_kib_per_min
        );
        assert_eq!((m.anon_first_kib, m.anon_last_kib), (50, 62));
        assert_eq!(m.anon_growth_after_warmup_kib, 2);
        // The second half, samples 3..6 (220, 230, 240): 240 - 220.
        assert_eq!(m.second_half_growth_kib, 20);
        assert!(m.flat);
        assert_eq!(m.series_kib, s.rss_kib);
    }

    #[test]
    fn anonymous_memory_above_the_bound_is_not_flat() {
        let s = series(&[100, 100, 100], &[10, 10, 10 + MEMORY_FLAT_BOUND_KIB + 1]);
        let m = memory_summary(&s, 0.0);
        assert_eq!(m.anon_growth_after_warmup_kib, MEMORY_FLAT_BOUND_KIB + 1);
        assert!(!m.flat);
        assert_eq!(m.slope_kib_per_min, 0.0);
    }

    #[test]
    fn a_run_shorter_than_the_warmup_uses_every_sample() {
        let s = series(&[100, 130], &[5, 6]);
        let m = memory_summary(&s, 10.0);
        assert_eq!(m.after_warmup_kib, 100);
        assert_eq!(m.growth_after_warmup_kib, 30);
        // Two samples 1 s apart, 30 KiB: 1800 KiB/min.
        assert!((m.slope_kib_per_min - 1800.0).abs() < 1e-9);
    }

    #[test]
    fn no_samples_is_not_flat() {
        let m = memory_summary(&series(&[], &[]), 1.0);
        assert_eq!((m.samples, m.max_kib, m.second_half_growth_kib), (0, 0, 0));
        assert!(!m.flat);
    }
}
