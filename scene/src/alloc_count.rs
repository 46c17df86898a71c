//! A counting global allocator, for measuring what code allocates: the fuzz harness (an
//! allocation out of proportion to the input is a finding) and the memory-accounting tests
//! (an estimate must match what a constructor really allocates).
//!
//! A binary opts in with `#[global_allocator] static A: CountingAlloc = CountingAlloc;`.
//! Counting is off until [`measure`] turns it on, so a binary that installs the allocator
//! pays one relaxed atomic load per allocation otherwise. The counters are global: every
//! thread's allocations count (rayon workers included), so callers run one measurement at a
//! time (the fuzz harness and the memory tests serialize their own) and measure in a test
//! binary of their own, where no unrelated test allocates at the same time. No lock is held
//! here: a measured call that never returns (a fuzz case stuck in a loop) must not block
//! every later measurement.
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicIsize, AtomicUsize, Ordering};

/// The allocator: the system allocator plus counters.
pub struct CountingAlloc;

static ON: AtomicBool = AtomicBool::new(false);
/// Bytes allocated minus bytes freed since the measurement began (frees of older memory
/// make it negative).
static LIVE: AtomicIsize = AtomicIsize::new(0);
static PEAK: AtomicIsize = AtomicIsize::new(0);
static LARGEST: AtomicUsize = AtomicUsize::new(0);
static TOTAL: AtomicUsize = AtomicUsize::new(0);
/// Allocations and frees seen while counting (for [`settle`]).
static EVENTS: AtomicUsize = AtomicUsize::new(0);

#[inline]
fn grew(by: usize) {
    let now = LIVE.fetch_add(by as isize, Ordering::Relaxed) + by as isize;
    PEAK.fetch_max(now, Ordering::Relaxed);
    LARGEST.fetch_max(by, Ordering::Relaxed);
    TOTAL.fetch_add(by, Ordering::Relaxed);
    EVENTS.fetch_add(1, Ordering::Relaxed);
}

#[inline]
fn shrank(by: usize) {
    LIVE.fetch_sub(by as isize, Ordering::Relaxed);
    EVENTS.fetch_add(1, Ordering::Relaxed);
}

// SAFETY: every method forwards to `System` with the caller's arguments unchanged; the
// counters are plain atomics that neither allocate nor unwind.
unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc(layout);
        if !p.is_null() && ON.load(Ordering::Relaxed) {
            grew(layout.size());
        }
        p
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc_zeroed(layout);
        if !p.is_null() && ON.load(Ordering::Relaxed) {
            grew(layout.size());
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout);
        if ON.load(Ordering::Relaxed) {
            shrank(layout.size());
        }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = System.realloc(ptr, layout, new_size);
        if !p.is_null() && ON.load(Ordering::Relaxed) {
            if new_size >= layout.size() {
                grew(new_size - layout.size());
            } else {
                shrank(layout.size() - new_size);
            }
        }
        p
    }
}

/// What a measured piece of code allocated.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Usage {
    /// Bytes still allocated at the end (allocated minus freed; negative if it freed more
    /// than it allocated).
    pub live: isize,
    /// The most bytes allocated at once during the measurement.
    pub peak: usize,
    /// The largest single allocation (or growth of one by `realloc`).
    pub largest: usize,
    /// Bytes allocated in all.
    pub total: usize,
}

/// Whether this binary installed [`CountingAlloc`] as its global allocator (a measured
/// allocation is seen).
pub fn installed() -> bool {
    let (_, u) = measure(|| std::hint::black_box(Box::new([0u8; 64])));
    u.total >= 64
}

/// Runs `f` with counting on and returns what it allocated; allocations of other threads
/// during `f` count too. One measurement at a time (see the module docs).
pub fn measure<R>(f: impl FnOnce() -> R) -> (R, Usage) {
    for c in [&LIVE, &PEAK] {
        c.store(0, Ordering::Relaxed);
    }
    LARGEST.store(0, Ordering::Relaxed);
    TOTAL.store(0, Ordering::Relaxed);
    ON.store(true, Ordering::SeqCst);
    let r = f();
    ON.store(false, Ordering::SeqCst);
    let usage = Usage {
        live: LIVE.load(Ordering::Relaxed),
        peak: PEAK.load(Ordering::Relaxed).max(0) as usize,
        largest: LARGEST.load(Ordering::Relaxed),
        total: TOTAL.load(Ordering::Relaxed),
    };
    (r, usage)
}

/// Waits (at most `limit`) until no thread has allocated or freed anything for five
/// consecutive 10 ms windows. Threads of earlier work wind down on their own time — a
/// dropped rayon pool's or tokio runtime's threads free their buffers after the drop
/// returns — and their frees would count against the next measurement; an exact
/// measurement in a binary that ran such work settles first. Returns whether it settled.
pub fn settle(limit: std::time::Duration) -> bool {
    let start = std::time::Instant::now();
    ON.store(true, Ordering::SeqCst);
    let mut quiet = 0;
    let mut last = EVENTS.load(Ordering::Relaxed);
    while quiet < 5 && start.elapsed() < limit {
        std::thread::sleep(std::time::Duration::from_millis(10));
        let now = EVENTS.load(Ordering::Relaxed);
        quiet = if now == last { quiet + 1 } else { 0 };
        last = now;
    }
    ON.store(false, Ordering::SeqCst);
    quiet >= 5
}
