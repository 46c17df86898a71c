//! The thread pool for long background work beside the frame loops: edge-index builds and
//! shadow-store updates (paper 000 §6.4–6.5). It is separate from rayon's global pool, which
//! the frame loops' per-pixel passes use: a build of seconds queued on the global pool would
//! hold every frame's passes behind it (measured: 2 s first frames on the dragon). Its
//! threads run at a lower scheduling priority (nice +10), so on a busy machine the frame
//! loops get the cores first and the background work takes what is left.
use std::sync::OnceLock;

/// Niceness added to the background threads.
pub const NICE: i32 = 10;

/// The background pool: one thread per core, at lower priority.
pub fn pool() -> &'static rayon::ThreadPool {
    static POOL: OnceLock<rayon::ThreadPool> = OnceLock::new();
    POOL.get_or_init(|| {
        let threads = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("background-{i}"))
            .start_handler(|_| lower_priority())
            .build()
            .unwrap_or_else(|e| {
                // Cannot start threads at all: run background work on the calling thread.
                tracing::error!("cannot start the background pool ({e}); background work runs inline");
                rayon::ThreadPoolBuilder::new().num_threads(1).use_current_thread().build().expect("a pool on the current thread")
            })
    })
}

/// Lowers the calling thread's priority by [`NICE`] (Linux: niceness is per thread).
fn lower_priority() {
    #[cfg(target_os = "linux")]
    // SAFETY: plain system calls on the calling thread's own id.
    unsafe {
        let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
        let now = libc::getpriority(libc::PRIO_PROCESS, tid);
        if libc::setpriority(libc::PRIO_PROCESS, tid, (now + NICE).min(19)) != 0 {
            tracing::debug!("background thread keeps its priority: setpriority failed");
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn runs_work_on_its_own_threads() {
        let name = super::pool().install(|| std::thread::current().name().map(str::to_string));
        assert!(name.is_some_and(|n| n.starts_with("background-")));
    }
}
