//! Clocks for in-process stage timings: a thread's CPU time (what other work on a busy
//! machine does not inflate, for one-thread runs) and the wall clock (for runs on a pool).
use std::time::Instant;

/// Milliseconds of CPU time of the calling thread.
pub fn thread_cpu_ms() -> f64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: a valid clock id and a valid pointer to a timespec.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 * 1e3 + ts.tv_nsec as f64 * 1e-6
}

/// Milliseconds of wall-clock time since the first call.
pub fn wall_ms() -> f64 {
    static START: std::sync::OnceLock<Instant> = std::sync::OnceLock::new();
    START.get_or_init(Instant::now).elapsed().as_secs_f64() * 1e3
}

/// Milliseconds of CPU time of the whole process (every thread: for work that runs on
/// threads this process does not own, such as a library's build threads).
pub fn process_cpu_ms() -> f64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: a valid clock id and a valid pointer to a timespec.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 * 1e3 + ts.tv_nsec as f64 * 1e-6
}

/// Median milliseconds of `f` by `clock` over `iterations` runs, after two warm-up runs.
pub fn median_ms(iterations: usize, clock: fn() -> f64, f: &mut dyn FnMut()) -> f64 {
    let mut v = Vec::with_capacity(iterations);
    for i in 0..iterations + 2 {
        let t0 = clock();
        f();
        if i >= 2 {
            v.push(clock() - t0);
        }
    }
    crate::stats::median(&v)
}
