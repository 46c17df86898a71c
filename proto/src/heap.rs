//! The C heap of a long-running process (the server's frame loops, a worker's batches).
//!
//! Every frame allocates and frees the same few megabytes: request batches (built by the
//! frame loop, freed by the worker links once sent), sample batches, encoded frames. With
//! glibc's defaults the freed memory at the top of the heap is returned to the kernel as
//! soon as 128 KiB are free there, and buffers above its mmap threshold are mapped and
//! unmapped each time, so the next frame takes a page fault for every 4 KiB it touches again
//! (hundreds a frame). Measured on `cornell` at 512² (`edgepoint-bench frame`, 2026-12-03):
//! building a rest frame's 25,000 requests took 0.61–0.68 ms with the defaults, 0.41–0.50 ms
//! keeping the memory. The process keeps up to [`TRIM_THRESHOLD`] of free heap instead and
//! serves buffers up to [`MMAP_THRESHOLD`] from the heap, where they are reused.

/// Free memory at the top of the heap kept before returning any to the kernel.
pub const TRIM_THRESHOLD: i32 = 64 << 20;
/// Allocations at least this large are mapped on their own (the default adapts up to 32
/// MiB anyway, but setting the trim threshold turns that adaptation off).
pub const MMAP_THRESHOLD: i32 = 32 << 20;

/// Keeps freed memory for reuse (see the module doc); glibc only, a no-op elsewhere.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes the allocator's tunables; called before heavy allocation.
    unsafe {
        let ok = libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1 && libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1;
        if !ok {
            tracing::debug!("the allocator kept its defaults (mallopt refused)");
        }
    }
}
