//! Software prefetch hints, for loops whose next random reads are known a few steps ahead
//! (edge-tree traversal, wedge searches, inserting a batch of samples into the Render
//! Cache): the loads of several steps then overlap instead of each waiting for memory.
//! Hints only: nothing is read, and on targets without the instruction they do nothing.

/// Asks the CPU to bring the cache line holding the start of `x` into the cache.
#[inline(always)]
pub fn prefetch<T>(x: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: prefetching is a hint; any address is allowed, this one is valid.
    unsafe {
        std::arch::x86_64::_mm_prefetch(x as *const T as *const i8, std::arch::x86_64::_MM_HINT_T0);
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = x;
}

/// [`prefetch`] of `x`'s first three cache lines when it is larger than one (a wide node).
#[inline(always)]
pub fn prefetch_lines<T>(x: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: prefetching is a hint; any address is allowed, even past `x`'s end.
    unsafe {
        std::arch::x86_64::_mm_prefetch(x as *const T as *const i8, std::arch::x86_64::_MM_HINT_T0);
        if std::mem::size_of::<T>() > 64 {
            std::arch::x86_64::_mm_prefetch((x as *const T as *const i8).wrapping_add(64), std::arch::x86_64::_MM_HINT_T0);
            std::arch::x86_64::_mm_prefetch((x as *const T as *const i8).wrapping_add(128), std::arch::x86_64::_MM_HINT_T0);
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = x;
}
