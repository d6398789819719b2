//! Sums over a window, in eight lanes: element `k` goes to lane `k % 8`, the lanes are
//! added pairwise at the end. A serial sum waits for each addition before the next
//! (a 4-cycle dependency per sample), eight lanes keep the adders busy; and the
//! rounding error grows with n/8 terms per lane instead of n (Higham 2002, section
//! 4.2: the error bound of a sum is proportional to the length of its longest chain
//! of additions).

const LANES: usize = 8;

/// `sum x`.
#[inline]
pub(crate) fn sum(x: &[f64]) -> f64 {
    lanes(x, |v| v)
}

/// `sum x^2`.
#[inline]
pub(crate) fn sum_sq(x: &[f64]) -> f64 {
    lanes(x, |v| v * v)
}

/// `(sum d^2, sum d^4)` with `d = x - mean`.
#[inline]
pub(crate) fn central_2_4(x: &[f64], mean: f64) -> (f64, f64) {
    let (mut m2, mut m4) = ([0.0f64; LANES], [0.0f64; LANES]);
    let chunks = x.chunks_exact(LANES);
    let tail = chunks.remainder();
    let mut add = |lane: usize, v: f64| {
        let d = v - mean;
        let d2 = d * d;
        m2[lane] += d2;
        m4[lane] += d2 * d2;
    };
    for c in chunks {
        for (lane, v) in c.iter().enumerate() {
            add(lane, *v);
        }
    }
    for (lane, v) in tail.iter().enumerate() {
        add(lane, *v);
    }
    (fold(&m2), fold(&m4))
}

/// The lanes added pairwise.
#[inline(always)]
fn fold(acc: &[f64; LANES]) -> f64 {
    ((acc[0] + acc[4]) + (acc[2] + acc[6])) + ((acc[1] + acc[5]) + (acc[3] + acc[7]))
}

/// `sum f(x)` in eight lanes, the tail in the first lanes.
#[inline(always)]
fn lanes(x: &[f64], f: impl Fn(f64) -> f64) -> f64 {
    let mut acc = [0.0f64; LANES];
    let chunks = x.chunks_exact(LANES);
    let tail = chunks.remainder();
    for c in chunks {
        for (a, v) in acc.iter_mut().zip(c) {
            *a += f(*v);
        }
    }
    for (a, v) in acc.iter_mut().zip(tail) {
        *a += f(*v);
    }
    fold(&acc)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Exact on integers (every partial sum is representable), for every length up to
    /// three chunks and a tail; closer to the exact sum than a serial one on values
    /// whose serial sum loses digits.
    #[test]
    fn lane_sums_are_the_sums() {
        for n in 0..30usize {
            let x: Vec<f64> = (0..n).map(|k| (k as f64) - 7.0).collect();
            let want: f64 = (0..n).map(|k| k as i64 - 7).sum::<i64>() as f64;
            let want_sq: f64 = (0..n).map(|k| (k as i64 - 7).pow(2)).sum::<i64>() as f64;
            assert_eq!(sum(&x), want, "n = {n}");
            assert_eq!(sum_sq(&x), want_sq, "n = {n}");
            let want_4: f64 = (0..n).map(|k| (k as i64 - 9).pow(4)).sum::<i64>() as f64;
            let want_2: f64 = (0..n).map(|k| (k as i64 - 9).pow(2)).sum::<i64>() as f64;
            assert_eq!(central_2_4(&x, 2.0), (want_2, want_4), "n = {n}");
        }
        // 1 followed by a million values of 1e-16 (exactly 1 + 1e-10): a serial sum
        // loses every small term against the 1 (each is below half its ulp); the
        // lanes lose only those in the 1's lane, an eighth.
        let mut x = vec![1e-16; 1_000_000];
        x[0] = 1.0;
        let exact = 1.0 + 1e-10;
        let serial: f64 = x.iter().sum();
        assert_eq!(serial, 1.0);
        assert!(
            (sum(&x) - exact).abs() < 0.126 * 1e-10,
            "{}",
            sum(&x) - exact
        );
    }
}
