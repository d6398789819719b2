//! Real-time scheduling of a hot-loop thread: `SCHED_FIFO` at a fixed priority, so that
//! a block waiting on a busy machine wakes its service before any normal process runs
//! (a `lab diagnose` beside the services, a build). Asked for with
//! `[service] realtime_priority = N` or `--realtime-priority N`; without it the thread
//! keeps the normal (`SCHED_OTHER`) policy.
//!
//! With `loop_mode = "spin"` a FIFO thread never yields its core; the kernel's real-time
//! throttling (by default 95 % of each second) is then all that leaves the rest to
//! other work. Use it with `event` (the default).

/// The priorities `SCHED_FIFO` takes on Linux.
pub const PRIORITY_RANGE: std::ops::RangeInclusive<u8> = 1..=99;

/// The calling thread could not be given the real-time policy.
#[derive(Debug, thiserror::Error)]
#[error(
    "cannot run the hot loop at SCHED_FIFO priority {priority} (it needs CAP_SYS_NICE, \
     or an `ulimit -r` of at least {priority}; leave realtime_priority out to run with \
     normal scheduling)"
)]
pub struct RealtimeError {
    pub priority: u8,
    #[source]
    pub source: std::io::Error,
}

/// Puts the calling thread under `SCHED_FIFO` at `priority` (1..=99); `None` leaves it
/// as it is. Call it first thing on the hot-loop thread: on Linux the policy belongs to
/// the thread, and threads it spawns inherit it.
pub fn enter(priority: Option<u8>) -> Result<(), RealtimeError> {
    let Some(priority) = priority else {
        return Ok(());
    };
    let param = libc::sched_param {
        sched_priority: i32::from(priority),
    };
    // SAFETY: `param` is a valid sched_param for the duration of the call; pid 0 is the
    // calling thread.
    let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if rc == 0 {
        Ok(())
    } else {
        Err(RealtimeError {
            priority,
            source: std::io::Error::last_os_error(),
        })
    }
}

/// The calling thread's policy and priority, as the kernel reports them.
pub fn current() -> (i32, i32) {
    let mut param = libc::sched_param { sched_priority: 0 };
    // SAFETY: both calls only read the calling thread's scheduling state into `param`.
    let policy = unsafe { libc::sched_getscheduler(0) };
    unsafe { libc::sched_getparam(0, &mut param) };
    (policy, param.sched_priority)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On a thread of its own (the policy stays with it): FIFO at the asked priority
    /// when the process may, else an error naming the priority and what it needs.
    #[test]
    fn a_thread_enters_fifo_or_says_why_not() {
        std::thread::spawn(|| {
            assert!(enter(None).is_ok());
            assert_eq!(current().0, libc::SCHED_OTHER);
            match enter(Some(7)) {
                Ok(()) => assert_eq!(current(), (libc::SCHED_FIFO, 7)),
                Err(e) => {
                    assert_eq!(e.source.raw_os_error(), Some(libc::EPERM), "{e}");
                    assert!(e.to_string().contains("SCHED_FIFO priority 7"), "{e}");
                    assert_eq!(current().0, libc::SCHED_OTHER);
                }
            }
        })
        .join()
        .unwrap();
    }
}
