//! Taking blocks never allocates once the estimator is built: a counting global
//! allocator watches the steady state (this binary holds this one test only, so no
//! other test thread allocates meanwhile).

mod common;

use common::*;
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use vibro_dsp::{EstimatorConfigRaw, SampleBlock};

struct Counting;

static COUNTING: AtomicBool = AtomicBool::new(false);
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn steady_state_block_intake_does_not_allocate() {
    let fs_hz = 25_600.0;
    let mut raw = EstimatorConfigRaw::new(fs_hz, [1.0; 3]);
    raw.full_scale_g = Some([10.0; 3]);
    let mut est = estimator(raw);
    let mut x = white_noise(&mut rng(1), 4 * fs_hz as usize, [0.5; 3]);
    for (f, a) in [(31.0, 2.0), (97.3, 0.5), (555.0, 0.2)] {
        let tone = Tone {
            frequency_hz: f,
            amplitude_g: [a; 3],
            phase_rad: [0.0, 1.0, 2.0],
        };
        add_tone(&mut x, &tone, fs_hz);
    }
    // Faults too: a NaN, a gap, a duplicate block.
    x[30_000][1] = f64::NAN;
    let blocks: Vec<&[[f64; 3]]> = x.chunks(256).collect();
    let mut order: Vec<usize> = (0..blocks.len()).filter(|&i| i != 150).collect();
    order.insert(200, 198);

    let mut estimates = 0usize;
    let mut tones = 0usize;
    COUNTING.store(true, Ordering::SeqCst);
    for &i in &order {
        let b = SampleBlock {
            seq: i as u64,
            t0_ns: (i as f64 * 256.0 * 1e9 / fs_hz).round() as u64,
            samples_raw: blocks[i],
        };
        let _ = est.push_block(&b, |e| {
            estimates += 1;
            tones += e.tones.len();
        });
    }
    COUNTING.store(false, Ordering::SeqCst);
    let allocations = ALLOCATIONS.load(Ordering::SeqCst);
    assert_eq!(estimates, 7);
    assert_eq!(tones, 21);
    assert_eq!(
        allocations, 0,
        "{allocations} allocations while taking blocks"
    );
}
