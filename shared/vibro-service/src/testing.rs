//! A service running in-process for tests (the `testing` feature): its
//! `run(config, shutdown)` on a thread of its own, stopped and joined on drop, so a
//! failing test never leaves a service holding its shared memory.
//!
//! ```no_run
//! use std::time::Duration;
//! use vibro_service::testing::{wait_until, Running};
//! # fn run(_: (), shutdown: vibro_service::Shutdown) -> anyhow::Result<u64> {
//! #     while !shutdown.is_triggered() { std::thread::sleep(Duration::from_millis(1)); }
//! #     Ok(0)
//! # }
//! let service = Running::start(run, ());
//! assert!(wait_until(Duration::from_secs(5), || true));
//! let summary = service.stop();
//! # let _ = summary;
//! ```

use crate::Shutdown;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// A service running in-process on its own thread.
pub struct Running<S> {
    shutdown: Shutdown,
    handle: Option<JoinHandle<anyhow::Result<S>>>,
}

impl<S: Send + 'static> Running<S> {
    /// Runs `run(config, shutdown)` (a service's blocking `run`) on a new thread.
    pub fn start<C, F>(run: F, config: C) -> Self
    where
        C: Send + 'static,
        F: FnOnce(C, Shutdown) -> anyhow::Result<S> + Send + 'static,
    {
        let shutdown = Shutdown::new();
        let token = shutdown.clone();
        let handle = std::thread::spawn(move || run(config, token));
        Self {
            shutdown,
            handle: Some(handle),
        }
    }

    /// Triggers the shutdown and returns the summary.
    ///
    /// # Panics
    ///
    /// If the service panicked or returned an error (this is test code).
    pub fn stop(mut self) -> S {
        self.shutdown.trigger();
        let handle = self.handle.take().expect("running");
        handle.join().expect("no panic").expect("clean stop")
    }
}

impl<S> Drop for Running<S> {
    fn drop(&mut self) {
        self.shutdown.trigger();
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// Polls `done` every millisecond until it holds or `timeout` passes.
pub fn wait_until(timeout: Duration, mut done: impl FnMut() -> bool) -> bool {
    let start = Instant::now();
    while start.elapsed() < timeout {
        if done() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    done()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn until_stopped(ticks_ms: u64, shutdown: Shutdown) -> anyhow::Result<u64> {
        let mut ticks = 0;
        while !shutdown.is_triggered() {
            std::thread::sleep(Duration::from_millis(ticks_ms));
            ticks += 1;
        }
        Ok(ticks)
    }

    #[test]
    fn a_running_service_stops_with_its_summary_and_on_drop() {
        let service = Running::start(until_stopped, 1);
        std::thread::sleep(Duration::from_millis(20));
        assert!(service.stop() > 0);
        let seen = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        {
            let seen = std::sync::Arc::clone(&seen);
            let _service = Running::start(
                move |(), shutdown: Shutdown| {
                    while !shutdown.is_triggered() {
                        std::thread::sleep(Duration::from_millis(1));
                    }
                    seen.store(true, std::sync::atomic::Ordering::Release);
                    Ok(())
                },
                (),
            );
        }
        // Dropped: the thread was stopped and joined.
        assert!(seen.load(std::sync::atomic::Ordering::Acquire));
        assert!(wait_until(Duration::from_millis(50), || true));
        assert!(!wait_until(Duration::from_millis(5), || false));
    }
}
