//! A synchronous stop signal for a command's blocking loop: SIGINT/SIGTERM handlers
//! that only note the signal, for the loop to ask between steps (no tokio runtime;
//! a service's own shutdown is [`crate::Shutdown`]).

use std::sync::atomic::{AtomicI32, Ordering};

/// The signal (SIGINT or SIGTERM) caught while a [`StopSignal`] is installed, or 0.
static CAUGHT_SIGNAL: AtomicI32 = AtomicI32::new(0);

extern "C" fn on_stop_signal(signal: libc::c_int) {
    // Async-signal-safe: one store to an atomic.
    CAUGHT_SIGNAL.store(signal, Ordering::Release);
}

/// SIGINT/SIGTERM handlers that only note the signal, so that a blocking loop (a
/// simulated flight into a log) stops between steps and finishes its file; dropping it restores the default
/// action (a second Ctrl-C after the flight ends kills as usual).
pub struct StopSignal(());

impl StopSignal {
    /// Installs the handlers; the signals caught before are forgotten.
    pub fn install() -> StopSignal {
        CAUGHT_SIGNAL.store(0, Ordering::Release);
        // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
        unsafe {
            libc::signal(
                libc::SIGINT,
                on_stop_signal as *const () as libc::sighandler_t,
            );
            libc::signal(
                libc::SIGTERM,
                on_stop_signal as *const () as libc::sighandler_t,
            );
        }
        StopSignal(())
    }

    /// The signal caught so far, if any.
    pub fn caught(&self) -> Option<&'static str> {
        match CAUGHT_SIGNAL.load(Ordering::Acquire) {
            0 => None,
            libc::SIGINT => Some("SIGINT"),
            libc::SIGTERM => Some("SIGTERM"),
            _ => Some("a signal"),
        }
    }
}

impl Drop for StopSignal {
    fn drop(&mut self) {
        // SAFETY: restores the default actions; no handler state is left behind.
        unsafe {
            libc::signal(libc::SIGINT, libc::SIG_DFL);
            libc::signal(libc::SIGTERM, libc::SIG_DFL);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_signal_is_noted_and_the_default_comes_back() {
        let stop = StopSignal::install();
        assert_eq!(stop.caught(), None);
        // SAFETY: raising a signal whose handler only stores to an atomic.
        unsafe { libc::raise(libc::SIGTERM) };
        assert_eq!(stop.caught(), Some("SIGTERM"));
        drop(stop);
        // Installed again, the earlier signal is forgotten.
        let stop = StopSignal::install();
        assert_eq!(stop.caught(), None);
    }
}
