#![no_main]
//! See `povins_fuzz::estimator`: also checks that the core allocates nothing while it runs
//! (a counting global allocator armed around the operations).
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, Ordering};

static ARMED: AtomicBool = AtomicBool::new(false);

struct NoAllocInCore;

// SAFETY: forwards to the system allocator.
unsafe impl GlobalAlloc for NoAllocInCore {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        if ARMED.swap(false, Ordering::SeqCst) {
            panic!("the estimator allocated {} bytes", l.size());
        }
        System.alloc(l)
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        System.dealloc(p, l)
    }
}

#[global_allocator]
static A: NoAllocInCore = NoAllocInCore;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    povins_fuzz::estimator_guarded(data, &|on| ARMED.store(on, Ordering::SeqCst))
});
