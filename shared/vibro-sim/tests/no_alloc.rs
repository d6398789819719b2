//! Producing chunks never allocates once the simulator is built: a counting global
//! allocator watches the steady state of a flight with tones, random vibration
//! (kurtosis 6, correlated axes, overlap-save blocks) and sensors. This binary holds
//! this one test only, so no other test thread allocates meanwhile.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use vibro_sim::{parse_scenario, Simulator};

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
fn producing_chunks_does_not_allocate() {
    let text = vibro_sim::scenario::EMBEDDED_SCENARIOS
        .iter()
        .find(|(id, _, _)| *id == "cyclone-4-short")
        .map(|(_, _, t)| {
            t.replace("duration_s = 20.0", "duration_s = 4.0").replace(
                "rms_g = [1.4, 1.4, 1.4]",
                "rms_g = [1.4, 1.4, 1.4]\nkurtosis = [6.0, 6.0, 6.0]\n\
                 coherence = [[1.0, 0.3, 0.0], [0.3, 1.0, 0.0], [0.0, 0.0, 1.0]]",
            )
        })
        .unwrap();
    let scenario = parse_scenario(&text, "no-alloc.toml", None).unwrap();
    let mut sim = Simulator::new(&scenario, Vec::new()).unwrap();
    // The first chunk runs the first overlap-save block; every later one is steady.
    let mut outputs = sim.next_chunk().unwrap().unwrap().accel_v().len();
    COUNTING.store(true, Ordering::SeqCst);
    let mut chunks = 0;
    // 4 s hold three 1.28 s overlap-save blocks of the 32768-tap filter.
    while let Some(chunk) = sim.next_chunk().unwrap() {
        outputs += chunk.accel_v().len();
        chunks += 1;
    }
    COUNTING.store(false, Ordering::SeqCst);
    assert_eq!(outputs, 3200);
    assert_eq!(chunks, 39);
    assert_eq!(ALLOCATIONS.load(Ordering::SeqCst), 0);
}
