//! Receive-to-publish latency: an HDR histogram per summary period and one for the
//! whole run. Recording is a bounded-array increment (no allocation), done once per
//! output message.

use anyhow::Context;
use hdrhistogram::Histogram;
use serde::Serialize;

/// Highest latency the histograms resolve (longer ones are recorded as this), ns.
const MAX_LATENCY_NS: u64 = 60_000_000_000;

/// Quantiles of a latency distribution, ns (0 when nothing was recorded).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct Quantiles {
    pub count: u64,
    pub p50_ns: u64,
    pub p99_ns: u64,
    pub max_ns: u64,
}

impl Quantiles {
    fn of(h: &Histogram<u64>) -> Self {
        if h.is_empty() {
            return Self::default();
        }
        Self {
            count: h.len(),
            p50_ns: h.value_at_quantile(0.5),
            p99_ns: h.value_at_quantile(0.99),
            max_ns: h.max(),
        }
    }

    pub fn to_json(&self) -> crate::JsonObject {
        let mut o = crate::JsonObject::new();
        o.u64("count", self.count)
            .u64("p50_ns", self.p50_ns)
            .u64("p99_ns", self.p99_ns)
            .u64("max_ns", self.max_ns);
        o
    }
}

/// The latency histograms of one service.
#[derive(Debug, Clone)]
pub struct Latency {
    period: Histogram<u64>,
    total: Histogram<u64>,
}

impl Latency {
    /// Allocates both histograms (1 ns .. 60 s, 3 significant digits).
    pub fn new() -> anyhow::Result<Self> {
        let make = || {
            Histogram::new_with_bounds(1, MAX_LATENCY_NS, 3)
                .context("creating a latency histogram (1 ns .. 60 s, 3 digits)")
        };
        Ok(Self {
            period: make()?,
            total: make()?,
        })
    }

    /// Records one latency; 0 is recorded as 1 ns (the histogram's floor).
    #[inline]
    pub fn record(&mut self, latency_ns: u64) {
        let v = latency_ns.max(1);
        self.period.saturating_record(v);
        self.total.saturating_record(v);
    }

    /// Quantiles since the last [`Self::reset_period`].
    pub fn period(&self) -> Quantiles {
        Quantiles::of(&self.period)
    }

    /// Quantiles over the whole run.
    pub fn total(&self) -> Quantiles {
        Quantiles::of(&self.total)
    }

    pub fn reset_period(&mut self) {
        self.period.reset();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_follow_the_recorded_values() {
        let mut l = Latency::new().unwrap();
        assert_eq!(l.total(), Quantiles::default());
        for v in 1..=1000u64 {
            l.record(v * 1000);
        }
        let q = l.total();
        assert_eq!(q.count, 1000);
        // 3 significant digits: within 0.1 %.
        assert!((q.p50_ns as f64 / 500_000.0 - 1.0).abs() < 2e-3, "{q:?}");
        assert!((q.p99_ns as f64 / 990_000.0 - 1.0).abs() < 2e-3, "{q:?}");
        l.reset_period();
        assert_eq!(l.period().count, 0);
        assert_eq!(l.total().count, 1000);
        l.record(u64::MAX);
        assert!(l.total().max_ns >= MAX_LATENCY_NS);
    }
}
