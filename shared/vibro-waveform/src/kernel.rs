//! Band-limited interpolation of the sensors' samples: a Kaiser-windowed sinc.
//!
//! `x(t) = sum_k x_k h(t/Ts - k)`, `h(u) = sinc(u) w(u / W)` over `|u| < W` samples, `w`
//! the Kaiser window of `beta` ([`HALF_WIDTH`], [`BETA`]). The windowed sinc passes
//! frequencies up to about `0.42 fs` within 1e-4 (an 80 dB Kaiser design's ripple,
//! transition `(A - 7.95) / (14.36 2W) fs`), so a vibration band up to a tenth of the
//! sensor rate (20..640 Hz at 6.4 kHz) is reproduced to better than 1e-4 in amplitude
//! and phase, where a linear interpolation between 8 samples per reading would lose
//! 4 % of a 640 Hz component. The kernel is tabulated at [`STEPS`] points per sample
//! and read linearly between them (relative error about `(pi / STEPS)^2 / 8`, 5e-6),
//! and its weights at each point are normalised to sum to 1, so that a constant (the
//! AC coupling's inverse leaves one) passes exactly.

/// Taps on each side of the interpolation point.
pub const HALF_WIDTH: usize = 16;
/// The Kaiser window's shape.
pub const BETA: f64 = 12.0;
/// Table points per sample.
pub const STEPS: usize = 2048;

/// The tabulated kernel.
#[derive(Debug, Clone)]
pub struct Kernel {
    /// `h(u)` at `u = -W + j / STEPS`, `j = 0..=2 W STEPS` (and one guard point).
    table: Vec<f64>,
}

/// The modified Bessel function of the first kind, order 0, by its power series.
fn bessel_i0(x: f64) -> f64 {
    let q = 0.25 * x * x;
    let (mut term, mut sum) = (1.0, 1.0);
    for k in 1..200 {
        term *= q / (k * k) as f64;
        sum += term;
        if term < 1e-17 * sum {
            break;
        }
    }
    sum
}

impl Default for Kernel {
    fn default() -> Self {
        Self::new()
    }
}

impl Kernel {
    /// Builds the table (allocates once).
    pub fn new() -> Self {
        let w = HALF_WIDTH as f64;
        let n = 2 * HALF_WIDTH * STEPS + 2;
        let i0_beta = bessel_i0(BETA);
        let table = (0..n)
            .map(|j| {
                let u = -w + j as f64 / STEPS as f64;
                if u.abs() >= w {
                    return 0.0;
                }
                let r = u / w;
                let window = bessel_i0(BETA * (1.0 - r * r).max(0.0).sqrt()) / i0_beta;
                let sinc = if j % STEPS == 0 && j != STEPS * HALF_WIDTH {
                    // A whole sample away: the sinc's zero, exactly (`sin(pi u)` would
                    // leave about 1e-17). So at a point on a sample the weights are
                    // exactly that sample's 1 and 0 elsewhere (`Weights::unit`).
                    0.0
                } else if u.abs() < 1e-12 {
                    1.0
                } else {
                    let pu = std::f64::consts::PI * u;
                    pu.sin() / pu
                };
                sinc * window
            })
            .collect();
        Self { table }
    }

    /// `h(u)`, `u` in samples, 0 outside `|u| < W`.
    #[inline]
    pub fn at(&self, u: f64) -> f64 {
        let x = (u + HALF_WIDTH as f64) * STEPS as f64;
        if !(x >= 0.0 && x < (2 * HALF_WIDTH * STEPS) as f64) {
            return 0.0;
        }
        let j = x as usize;
        let f = x - j as f64;
        self.table[j] + f * (self.table[j + 1] - self.table[j])
    }

    /// The interpolated value at fractional sample position `x` of the samples
    /// `get(k)` (three axes at once). The caller guarantees that the taps
    /// `floor(x) - W + 1 ..= floor(x) + W` exist.
    #[inline]
    pub fn interpolate(&self, x: f64, get: impl FnMut(i64) -> [f64; 3]) -> [f64; 3] {
        let k0 = x.floor();
        let weights = self.weights(x - k0);
        weights.interpolate(k0 as i64, get)
    }

    /// The taps' weights at fractional offset `frac` in `[0, 1)`: tap `i` (sample
    /// `floor(x) - W + 1 + i`) weighs `h(frac + W - 1 - i)`, and their sum's inverse.
    pub fn weights(&self, frac: f64) -> Weights {
        let w = HALF_WIDTH as i64;
        let mut h = [0.0; 2 * HALF_WIDTH];
        let mut sum_w = 0.0;
        // The same operations in the same order as a tap-by-tap evaluation.
        for (i, hi) in h.iter_mut().enumerate() {
            *hi = self.at(frac + (w - 1 - i as i64) as f64);
            sum_w += *hi;
        }
        let inv_sum = 1.0 / sum_w;
        // On a sample: one weight 1, the others 0, their sum 1.
        let ones = h.iter().filter(|x| **x == 1.0).count();
        let zeros = h.iter().filter(|x| **x == 0.0).count();
        let unit = (ones == 1 && zeros == h.len() - 1 && inv_sum == 1.0)
            .then(|| h.iter().position(|x| *x == 1.0))
            .flatten();
        Weights {
            frac_bits: frac.to_bits(),
            h,
            inv_sum,
            unit,
        }
    }
}

/// The kernel's normalised taps at one fractional offset ([`Kernel::weights`]). A grid
/// whose step is a fraction of the sample period meets the same few offsets again and
/// again: a caller keeps these and interpolates with them, bit for bit what
/// [`Kernel::interpolate`] gives at that offset.
#[derive(Debug, Clone, Copy)]
pub struct Weights {
    frac_bits: u64,
    h: [f64; 2 * HALF_WIDTH],
    inv_sum: f64,
    /// The tap whose weight is 1 when all others are 0 (a point on a sample): the
    /// interpolation is that sample. `0.0 + s` is what the sum gives, bit for bit,
    /// for finite taps (each `0 * s` adds +0, and `+0 + -0` is `+0`); a non-finite
    /// neighbour would make the sum NaN where the exact kernel, whose taps there are
    /// 0, gives the sample (the stage refuses non-finite blocks before its ring).
    unit: Option<usize>,
}

impl Weights {
    /// The offset these weights are for, as `f64::to_bits`.
    #[inline]
    pub fn frac_bits(&self) -> u64 {
        self.frac_bits
    }

    /// The interpolated value between samples `k0 - W + 1 ..= k0 + W` of `get(k)`.
    #[inline]
    pub fn interpolate(&self, k0: i64, mut get: impl FnMut(i64) -> [f64; 3]) -> [f64; 3] {
        let first = k0 - HALF_WIDTH as i64 + 1;
        if let Some(i) = self.unit {
            return on_sample(get(first + i as i64));
        }
        let mut acc = [0.0; 3];
        for (i, h) in self.h.iter().enumerate() {
            let s = get(first + i as i64);
            acc[0] += h * s[0];
            acc[1] += h * s[1];
            acc[2] += h * s[2];
        }
        let inv = self.inv_sum;
        [acc[0] * inv, acc[1] * inv, acc[2] * inv]
    }

    /// [`Self::interpolate_slice`] at two points at once, `(self, taps)` and `(other,
    /// other_taps)`: each point's sums in the same order as alone (bit for bit), the
    /// two interleaved so that neither waits on its own additions.
    #[inline]
    pub fn interpolate_pair(
        &self,
        taps: &[[f64; 3]; 2 * HALF_WIDTH],
        other: &Weights,
        other_taps: &[[f64; 3]; 2 * HALF_WIDTH],
    ) -> ([f64; 3], [f64; 3]) {
        if let (Some(i), Some(j)) = (self.unit, other.unit) {
            return (on_sample(taps[i]), on_sample(other_taps[j]));
        }
        let (mut a, mut b) = ([0.0; 3], [0.0; 3]);
        for i in 0..2 * HALF_WIDTH {
            let (ha, sa) = (self.h[i], taps[i]);
            let (hb, sb) = (other.h[i], other_taps[i]);
            a[0] += ha * sa[0];
            a[1] += ha * sa[1];
            a[2] += ha * sa[2];
            b[0] += hb * sb[0];
            b[1] += hb * sb[1];
            b[2] += hb * sb[2];
        }
        let (ia, ib) = (self.inv_sum, other.inv_sum);
        (
            [a[0] * ia, a[1] * ia, a[2] * ia],
            [b[0] * ib, b[1] * ib, b[2] * ib],
        )
    }

    /// [`Self::interpolate`] over `2 W` consecutive samples.
    #[inline]
    pub fn interpolate_slice(&self, taps: &[[f64; 3]; 2 * HALF_WIDTH]) -> [f64; 3] {
        if let Some(i) = self.unit {
            return on_sample(taps[i]);
        }
        let mut acc = [0.0; 3];
        for (h, s) in self.h.iter().zip(taps) {
            acc[0] += h * s[0];
            acc[1] += h * s[1];
            acc[2] += h * s[2];
        }
        let inv = self.inv_sum;
        [acc[0] * inv, acc[1] * inv, acc[2] * inv]
    }
}

/// The interpolation at a point on sample `s` (`Weights::unit`): `0.0 + s`, as the
/// weighted sum gives it.
#[inline]
fn on_sample(s: [f64; 3]) -> [f64; 3] {
    [0.0 + s[0], 0.0 + s[1], 0.0 + s[2]]
}

/// The last few offsets' [`Weights`] (a fixed ring, allocated once): the grid's points
/// repeat a short cycle of offsets when its step is a whole fraction of the sample
/// period (one offset when they coincide with samples).
#[derive(Debug, Clone)]
pub struct WeightsCache {
    entries: Vec<Weights>,
    /// The slot that answered last, and the next slot to fill.
    last: usize,
    next: usize,
}

/// Offsets a [`WeightsCache`] holds.
pub const CACHED_OFFSETS: usize = 64;

impl Default for WeightsCache {
    fn default() -> Self {
        Self::new()
    }
}

impl WeightsCache {
    pub fn new() -> Self {
        Self {
            entries: Vec::with_capacity(CACHED_OFFSETS),
            last: 0,
            next: 0,
        }
    }

    /// The weights at offset `frac` (bit for bit [`Kernel::weights`]).
    #[inline]
    pub fn get(&mut self, kernel: &Kernel, frac: f64) -> &Weights {
        let i = self.slot(kernel, frac);
        &self.entries[i]
    }

    /// The weights in slot `i` of [`Self::slot`]: valid through the next lookup (a miss
    /// never replaces the slot the previous lookup returned), not beyond.
    #[inline]
    pub fn entry(&self, i: usize) -> &Weights {
        &self.entries[i]
    }

    /// The slot holding the weights at offset `frac`, computed if missing.
    #[inline]
    pub fn slot(&mut self, kernel: &Kernel, frac: f64) -> usize {
        let bits = frac.to_bits();
        let n = self.entries.len();
        // The offsets cycle: the slot after the last hit is the likely one.
        for step in 0..n {
            // `(last + step) % n` without a division (`last < n`, `step < n`).
            let mut i = self.last + step;
            if i >= n {
                i -= n;
            }
            if self.entries[i].frac_bits == bits {
                self.last = i;
                return i;
            }
        }
        let w = kernel.weights(frac);
        let i = if n < CACHED_OFFSETS {
            self.entries.push(w);
            n
        } else {
            // Never the slot the previous lookup returned: two slots looked up in a
            // row both stay valid (the stage interpolates two points at once).
            let mut i = self.next;
            if i == self.last {
                i = (i + 1) % CACHED_OFFSETS;
            }
            self.entries[i] = w;
            self.next = (i + 1) % CACHED_OFFSETS;
            i
        };
        self.last = i;
        i
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// The tap-by-tap evaluation the cached weights replace.
    fn interpolate_tap_by_tap(k: &Kernel, x: f64, get: impl Fn(i64) -> [f64; 3]) -> [f64; 3] {
        let k0 = x.floor();
        let frac = x - k0;
        let k0 = k0 as i64;
        let w = HALF_WIDTH as i64;
        let mut acc = [0.0; 3];
        let mut sum_w = 0.0;
        for j in (k0 - w + 1)..=(k0 + w) {
            let h = k.at(frac + (k0 - j) as f64);
            let s = get(j);
            acc[0] += h * s[0];
            acc[1] += h * s[1];
            acc[2] += h * s[2];
            sum_w += h;
        }
        let inv = 1.0 / sum_w;
        [acc[0] * inv, acc[1] * inv, acc[2] * inv]
    }

    #[test]
    fn cached_weights_interpolate_bit_for_bit() {
        let k = Kernel::new();
        let s = |i: i64| {
            let t = i as f64 * 0.013;
            [t.sin(), (1.7 * t).cos() * 3.0, 1e-3 * t * t]
        };
        let mut cache = WeightsCache::new();
        // Offsets that repeat (a quarter-sample grid) and ones that do not, past the
        // cache's size so that slots are replaced.
        for j in 0..600 {
            let x = if j % 2 == 0 {
                40.0 + j as f64 * 0.25
            } else {
                40.0 + j as f64 * 0.137
            };
            let want = interpolate_tap_by_tap(&k, x, s);
            let k0 = x.floor();
            let via_cache = cache.get(&k, x - k0).interpolate(k0 as i64, s);
            let first = k0 as i64 - HALF_WIDTH as i64 + 1;
            let taps: [[f64; 3]; 2 * HALF_WIDTH] = std::array::from_fn(|i| s(first + i as i64));
            let via_slice = k.weights(x - k0).interpolate_slice(&taps);
            let other: [[f64; 3]; 2 * HALF_WIDTH] =
                std::array::from_fn(|i| s(first + 7 + i as i64));
            let (via_pair, other_pair) =
                k.weights(x - k0)
                    .interpolate_pair(&taps, &k.weights(0.3), &other);
            let other_alone = k.weights(0.3).interpolate_slice(&other);
            for a in 0..3 {
                assert_eq!(want[a].to_bits(), via_cache[a].to_bits(), "x {x} axis {a}");
                assert_eq!(want[a].to_bits(), via_slice[a].to_bits(), "x {x} axis {a}");
                assert_eq!(want[a].to_bits(), via_pair[a].to_bits(), "x {x} axis {a}");
                assert_eq!(other_alone[a].to_bits(), other_pair[a].to_bits(), "x {x}");
                assert_eq!(want[a].to_bits(), k.interpolate(x, s)[a].to_bits(), "x {x}");
            }
        }
    }

    /// On a sample the kernel's weights are exactly 1 there and 0 elsewhere, and the
    /// shortcut gives what the weighted sum gives, bit for bit: signed zeros, tiny and
    /// huge values among the taps.
    #[test]
    fn a_point_on_a_sample_is_that_sample_bit_for_bit() {
        let k = Kernel::new();
        for u in 1..HALF_WIDTH as i64 {
            assert_eq!(k.at(u as f64).to_bits(), 0.0f64.to_bits(), "u {u}");
            assert_eq!(k.at(-u as f64).to_bits(), 0.0f64.to_bits(), "u {u}");
        }
        assert_eq!(k.at(0.0), 1.0);
        let w = k.weights(0.0);
        assert_eq!(w.unit, Some(HALF_WIDTH - 1));
        assert!(k.weights(0.25).unit.is_none() && k.weights(1e-9).unit.is_none());
        let values = [-0.0, 0.0, 1e-300, -3.5, 2.0e300, 7.25e-3, -1e-310];
        let s = |i: i64| {
            let v = |o: i64| values[(i + o).rem_euclid(values.len() as i64) as usize];
            [v(0), v(3), v(5)]
        };
        let mut cache = WeightsCache::new();
        for x in 40..60 {
            let x = x as f64;
            let want = interpolate_tap_by_tap(&k, x, s);
            let k0 = x as i64;
            let first = k0 - HALF_WIDTH as i64 + 1;
            let taps: [[f64; 3]; 2 * HALF_WIDTH] = std::array::from_fn(|i| s(first + i as i64));
            let (pair, _) = w.interpolate_pair(&taps, &k.weights(0.0), &taps);
            let got = [
                k.interpolate(x, s),
                cache.get(&k, 0.0).interpolate(k0, s),
                w.interpolate_slice(&taps),
                pair,
            ];
            for g in got {
                for a in 0..3 {
                    assert_eq!(want[a].to_bits(), g[a].to_bits(), "x {x} axis {a}");
                    assert_eq!(g[a].to_bits(), (0.0 + s(k0)[a]).to_bits(), "x {x} axis {a}");
                }
            }
        }
    }

    /// Two lookups in a row, the second a miss on a full cache, leave the first's slot
    /// holding its offset's weights.
    #[test]
    fn a_miss_keeps_the_previous_lookups_slot() {
        let k = Kernel::new();
        let mut cache = WeightsCache::new();
        let fracs: Vec<f64> = (0..CACHED_OFFSETS + 40)
            .map(|i| i as f64 / 1000.0)
            .collect();
        for &f in &fracs[..CACHED_OFFSETS] {
            cache.slot(&k, f);
        }
        // Each old offset is the next to be replaced when it is looked up again.
        for (n, &new) in fracs[CACHED_OFFSETS..].iter().enumerate() {
            let old = fracs[n];
            let a = cache.slot(&k, old);
            let b = cache.slot(&k, new);
            assert_eq!(cache.entry(a).frac_bits(), old.to_bits(), "{n}");
            assert_eq!(cache.entry(b).frac_bits(), new.to_bits(), "{n}");
        }
    }

    #[test]
    fn reproduces_samples_and_a_band_limited_tone() {
        let k = Kernel::new();
        // At integer positions the kernel is 1 at 0 and 0 elsewhere.
        assert!((k.at(0.0) - 1.0).abs() < 1e-12);
        assert!(k.at(3.0).abs() < 1e-12);
        // A 640 Hz tone at 6.4 kHz (a tenth of the rate) between its samples.
        let fs = 6400.0;
        let f = 640.0;
        let s = |t: f64| (2.0 * PI * f * t + 0.4).sin();
        let mut worst: f64 = 0.0;
        for j in 0..200 {
            let x = 100.0 + j as f64 * 0.137;
            let v = k.interpolate(x, |i| [s(i as f64 / fs); 3]);
            worst = worst.max((v[0] - s(x / fs)).abs());
        }
        assert!(worst < 2e-4, "worst {worst}");
        // A tenth as fast: far better.
        let s2 = |t: f64| (2.0 * PI * 64.0 * t + 0.4).sin();
        let mut worst2: f64 = 0.0;
        for j in 0..200 {
            let x = 100.0 + j as f64 * 0.137;
            let v = k.interpolate(x, |i| [s2(i as f64 / fs); 3]);
            worst2 = worst2.max((v[0] - s2(x / fs)).abs());
        }
        assert!(worst2 < 2e-5, "worst {worst2}");
    }
}
