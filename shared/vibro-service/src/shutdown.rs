//! The shutdown signal that `run(config, shutdown)` takes (mini-redis style: when /
//! tell / wait). The hot loop reads an atomic flag (one relaxed load per wake-up or
//! spin); tokio tasks await [`Shutdown::triggered`].

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use tokio::sync::watch;

/// A cloneable shutdown token: every clone sees [`Shutdown::trigger`].
#[derive(Clone, Debug)]
pub struct Shutdown {
    flag: Arc<AtomicBool>,
    tx: Arc<watch::Sender<bool>>,
}

impl Default for Shutdown {
    fn default() -> Self {
        Self::new()
    }
}

impl Shutdown {
    pub fn new() -> Self {
        let (tx, _rx) = watch::channel(false);
        Self {
            flag: Arc::new(AtomicBool::new(false)),
            tx: Arc::new(tx),
        }
    }

    /// Asks every holder of a clone to stop. Idempotent.
    pub fn trigger(&self) {
        self.flag.store(true, Ordering::Release);
        self.tx.send_replace(true);
    }

    /// The flag itself, for loops that take an `&AtomicBool` (`vibro_log`).
    pub fn flag(&self) -> &AtomicBool {
        &self.flag
    }

    /// Whether shutdown was asked for: cheap enough for a hot loop.
    #[inline]
    pub fn is_triggered(&self) -> bool {
        self.flag.load(Ordering::Acquire)
    }

    /// Resolves once shutdown is asked for (at once if it already was).
    pub async fn triggered(&self) {
        let mut rx = self.tx.subscribe();
        // The sender lives in `self`, so `wait_for` cannot fail with a closed channel.
        let _ = rx.wait_for(|stop| *stop).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_clone_sees_the_trigger_and_waiters_wake() {
        let a = Shutdown::new();
        let b = a.clone();
        assert!(!b.is_triggered());
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .build()
            .unwrap();
        rt.block_on(async {
            let waiter = tokio::spawn({
                let b = b.clone();
                async move { b.triggered().await }
            });
            tokio::time::sleep(std::time::Duration::from_millis(10)).await;
            a.trigger();
            tokio::time::timeout(std::time::Duration::from_secs(1), waiter)
                .await
                .unwrap()
                .unwrap();
            // Already triggered: resolves at once.
            b.triggered().await;
        });
        assert!(b.is_triggered());
    }
}
