//! The services' clock.

/// `CLOCK_MONOTONIC` now, in ns. The clock is system-wide on Linux, so stamps taken by
/// different processes (a producer's `publish_ns`, a consumer's `recv_ns`) subtract into
/// a meaningful latency. Never goes backwards; not related to wall-clock time.
#[inline]
pub fn now_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `clock_gettime` only writes the `timespec` we own; CLOCK_MONOTONIC exists
    // on every Linux kernel (it cannot fail with a valid pointer and clock id).
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    if rc != 0 {
        return 0;
    }
    (ts.tv_sec as u64)
        .saturating_mul(1_000_000_000)
        .saturating_add(ts.tv_nsec as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_clock_is_monotonic_and_in_nanoseconds() {
        let a = now_ns();
        std::thread::sleep(std::time::Duration::from_millis(5));
        let b = now_ns();
        assert!(b > a);
        // 5 ms slept: at least 5e6 ns, and not seconds (which would mean wrong units).
        assert!((5_000_000..1_000_000_000).contains(&(b - a)), "{}", b - a);
    }
}
