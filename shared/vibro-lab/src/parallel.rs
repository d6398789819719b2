//! Work spread over threads, the results in the order of the work.

/// `f` over `items`, `threads` at once, the results in the items' order.
pub(crate) fn in_parallel<T: Sync, R: Send>(
    items: &[T],
    threads: usize,
    f: impl Fn(usize, &T) -> R + Sync,
) -> Vec<R> {
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results = std::sync::Mutex::new(Vec::with_capacity(items.len()));
    std::thread::scope(|s| {
        for _ in 0..threads.clamp(1, items.len().max(1)) {
            s.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some(x) = items.get(i) else { break };
                let r = f(i, x);
                if let Ok(mut v) = results.lock() {
                    v.push((i, r));
                }
            });
        }
    });
    let mut v = results.into_inner().unwrap_or_default();
    v.sort_by_key(|(i, _)| *i);
    v.into_iter().map(|(_, r)| r).collect()
}

/// The most threads the lab's fits use at once in this process (0: no limit): see
/// [`limit_threads`].
static LIMIT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// Caps the threads every fit of this process spreads its work over (`n = 0` lifts the
/// cap): a batch that runs one job per core in several processes (`vibro-archive`'s
/// workers, a Dask worker's task) gives each job one thread, so that its processes do
/// not compete for the cores. The results do not depend on it (work is spread in
/// order-preserving chunks). Returns the cap it replaces, for the caller to put back:
/// a job run inside someone else's process (a Python session's) leaves it as it was.
pub fn limit_threads(n: usize) -> usize {
    LIMIT.swap(n, std::sync::atomic::Ordering::Relaxed)
}

/// The cap [`limit_threads`] set (0: none).
pub fn thread_limit() -> usize {
    LIMIT.load(std::sync::atomic::Ordering::Relaxed)
}

/// The threads this machine runs at once (1 when it cannot tell), within
/// [`limit_threads`]'s cap.
pub(crate) fn available() -> usize {
    let machine = std::thread::available_parallelism().map_or(1, |n| n.get());
    match LIMIT.load(std::sync::atomic::Ordering::Relaxed) {
        0 => machine,
        cap => machine.min(cap),
    }
}
