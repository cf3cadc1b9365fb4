//! A global allocator that counts allocations per thread.
//!
//! Install it in a test binary, then measure a closure:
//!
//! ```ignore
//! use test_support::alloc::{CountingAllocator, count_allocations};
//! #[global_allocator]
//! static ALLOC: CountingAllocator = CountingAllocator;
//!
//! let (_, stats) = count_allocations(|| control_tick(&mut state));
//! assert_eq!(stats.allocations, 0, "steady-state tick allocated: {stats:?}");
//! ```
//!
//! Counters are thread-local so the test harness's other threads (and other tests running in
//! parallel) do not disturb a measurement. Work a measured closure hands to other threads is not
//! counted by [`count_allocations`]; threads that call [`watch_this_thread`] (a bus worker's start
//! hook, say) also add every heap operation to one process-wide counter, [`watched_heap_ops`].
#![allow(unsafe_code)] // implementing GlobalAlloc is unsafe by definition

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

thread_local! {
    // `const` initialisation: reading these never allocates, so the allocator may use them.
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
    static REALLOCATIONS: Cell<u64> = const { Cell::new(0) };
    static DEALLOCATIONS: Cell<u64> = const { Cell::new(0) };
    static BYTES: Cell<u64> = const { Cell::new(0) };
    static WATCHED: Cell<bool> = const { Cell::new(false) };
}

/// Heap operations (allocations, reallocations, frees) on watched threads, all together.
static WATCHED_OPS: AtomicU64 = AtomicU64::new(0);

/// Counts this thread's heap operations in [`watched_heap_ops`] from now on.
pub fn watch_this_thread() {
    WATCHED.with(|w| w.set(true));
}

/// Heap operations on every watched thread so far.
pub fn watched_heap_ops() -> u64 {
    WATCHED_OPS.load(Ordering::Relaxed)
}

/// The system allocator with per-thread counters. See the module docs.
#[derive(Debug, Clone, Copy, Default)]
pub struct CountingAllocator;

fn bump(counter: &'static std::thread::LocalKey<Cell<u64>>, by: u64) {
    // `try_with` fails only while the thread's locals are being torn down; nothing to count then.
    let _ = counter.try_with(|c| c.set(c.get().wrapping_add(by)));
}

fn bump_watched() {
    if WATCHED.try_with(Cell::get).unwrap_or(false) {
        WATCHED_OPS.fetch_add(1, Ordering::Relaxed);
    }
}

// SAFETY: every method forwards to `System` with the caller's arguments unchanged; the counting
// touches only const-initialised thread-locals, which neither allocate nor unwind.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        bump_watched();
        bump(&ALLOCATIONS, 1);
        bump(&BYTES, layout.size() as u64);
        // SAFETY: forwarded contract.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        bump_watched();
        bump(&ALLOCATIONS, 1);
        bump(&BYTES, layout.size() as u64);
        // SAFETY: forwarded contract.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        bump_watched();
        bump(&DEALLOCATIONS, 1);
        // SAFETY: forwarded contract.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        bump_watched();
        bump(&REALLOCATIONS, 1);
        bump(&BYTES, new_size as u64);
        // SAFETY: forwarded contract.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// What a measured closure did to the heap, on the measuring thread.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct AllocStats {
    /// Calls to `alloc` and `alloc_zeroed`.
    pub allocations: u64,
    /// Calls to `realloc` (a growing `Vec`, for instance).
    pub reallocations: u64,
    /// Calls to `dealloc`.
    pub deallocations: u64,
    /// Bytes requested by allocations and reallocations.
    pub bytes: u64,
}

impl AllocStats {
    /// True when the closure neither allocated, reallocated nor freed memory.
    pub fn is_zero(&self) -> bool {
        self.allocations == 0 && self.reallocations == 0 && self.deallocations == 0
    }
}

fn snapshot() -> AllocStats {
    AllocStats {
        allocations: ALLOCATIONS.with(Cell::get),
        reallocations: REALLOCATIONS.with(Cell::get),
        deallocations: DEALLOCATIONS.with(Cell::get),
        bytes: BYTES.with(Cell::get),
    }
}

/// Runs `f` on this thread and returns its result with the heap activity it caused.
///
/// # Panics
/// When [`CountingAllocator`] is not the global allocator of the running binary: a measurement
/// that always reads zero would make every "no allocation" test pass vacuously.
pub fn count_allocations<R>(f: impl FnOnce() -> R) -> (R, AllocStats) {
    assert_installed();
    let before = snapshot();
    let out = f();
    let after = snapshot();
    let stats = AllocStats {
        allocations: after.allocations - before.allocations,
        reallocations: after.reallocations - before.reallocations,
        deallocations: after.deallocations - before.deallocations,
        bytes: after.bytes - before.bytes,
    };
    (out, stats)
}

/// Panics unless [`CountingAllocator`] is installed with `#[global_allocator]` in this binary.
pub fn assert_installed() {
    let before = ALLOCATIONS.with(Cell::get);
    let probe = std::hint::black_box(Box::new(0u64));
    drop(probe);
    let after = ALLOCATIONS.with(Cell::get);
    assert!(
        after > before,
        "CountingAllocator is not the global allocator of this test binary; add \
         `#[global_allocator] static ALLOC: test_support::alloc::CountingAllocator = \
         test_support::alloc::CountingAllocator;`"
    );
}
