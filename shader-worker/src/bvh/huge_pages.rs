//! Arrays a traversal reads at random — an object's BVH nodes and leaf blocks — in fresh
//! anonymous memory advised for transparent huge pages (`madvise(MADV_HUGEPAGE)`, 2 MB
//! pages), as Embree's allocator does for its BVHs (its `os_malloc`). The dragon's nodes
//! and blocks span ~50 MB: ~12,000 pages of 4 KB, far beyond the TLB's reach, so an
//! incoherent ray paid a page walk on most node and block visits; in 2 MB pages they are
//! ~25. Small arrays (a top level, a small mesh) and other systems stay in a `Vec`; when
//! the kernel gives no huge pages the memory is ordinary and only the advice is lost.
//!
//! A dropped array's mapping is kept for the next build ([`Spare`], at most
//! [`SPARE_BYTES`]): the first touch of fresh memory is most of a build's last phase on
//! this machine (the kernel clears each huge page, and in a virtual machine the host may
//! fault it in as well: the dragon's blocks took 28 ms in some builds and 115 ms in others,
//! every page a huge one). A rebuild (a scene reloaded; the rays bench's repeats) then
//! writes into memory already mapped, as a `malloc` that reuses freed blocks does for
//! Embree's builds, whose first build in a process is the slow one too.
use std::ops::Deref;

/// Arrays at least this large are mapped for huge pages.
const HUGE_PAGE: usize = 2 << 20;
/// Most bytes of dropped mappings kept for reuse (the dragon's nodes and blocks are
/// ~60 MB).
#[cfg(target_os = "linux")]
const SPARE_BYTES: usize = 128 << 20;

/// An immutable array of `T`, in huge-page-advised memory when large (see the module).
pub struct HugeArray<T: Copy> {
    /// The values, wherever `storage` keeps them: read without matching on the storage
    /// (the traversal indexes nodes and blocks in its inner loop).
    data: *const T,
    len: usize,
    storage: Storage<T>,
}

// SAFETY: `data` points into `storage`, which the array owns exclusively (a Vec's
// buffer or a Mapping, unmapped only on drop) and never mutates after `collect`.
unsafe impl<T: Copy + Send> Send for HugeArray<T> {}
// SAFETY: shared access is read-only.
unsafe impl<T: Copy + Sync> Sync for HugeArray<T> {}

/// What owns the values (held to be freed on drop; read through `data`).
#[allow(dead_code)]
enum Storage<T> {
    Heap(Vec<T>),
    #[cfg(target_os = "linux")]
    Mapped(Mapping<T>),
}

/// `len` values at `data`, inside the anonymous mapping `[base, base + map_len)`.
#[cfg(target_os = "linux")]
struct Mapping<T> {
    base: *mut libc::c_void,
    map_len: usize,
    data: *mut T,
    len: usize,
}

#[cfg(target_os = "linux")]
impl<T> Drop for Mapping<T> {
    fn drop(&mut self) {
        if let Some(unkept) = Spare::keep(self.base as usize, self.map_len) {
            // SAFETY: `base`/`map_len` are a mapping this array owned, unmapped once (the
            // spares gave it up).
            unsafe { libc::munmap(unkept.0 as *mut libc::c_void, unkept.1) };
        }
    }
}

/// Mappings of dropped arrays, as (base address, length), kept for [`Mapping::new`] to
/// reuse (see the module): up to [`SPARE_BYTES`] in all, the newest kept.
#[cfg(target_os = "linux")]
struct Spare;

#[cfg(target_os = "linux")]
static SPARES: std::sync::Mutex<Vec<(usize, usize)>> = std::sync::Mutex::new(Vec::new());

#[cfg(target_os = "linux")]
impl Spare {
    /// Keeps the mapping `(base, len)`; returns the mappings that no longer fit (to unmap).
    fn keep(base: usize, len: usize) -> Option<(usize, usize)> {
        if len > SPARE_BYTES {
            return Some((base, len));
        }
        let mut spares = SPARES.lock().unwrap_or_else(|e| e.into_inner());
        spares.push((base, len));
        let mut total: usize = spares.iter().map(|s| s.1).sum();
        let mut unkept = Vec::new();
        while total > SPARE_BYTES {
            let oldest = spares.remove(0);
            total -= oldest.1;
            unkept.push(oldest);
        }
        drop(spares);
        // All but one unmapped here, the last by the caller (usually there is none).
        let last = unkept.pop();
        for (b, l) in unkept {
            // SAFETY: a mapping a dropped array gave up, now in no list.
            unsafe { libc::munmap(b as *mut libc::c_void, l) };
        }
        last
    }

    /// A kept mapping of at least `len` bytes and at most twice that (a larger one would
    /// hold memory the array does not use), taken out of the list.
    fn take(len: usize) -> Option<(usize, usize)> {
        let mut spares = SPARES.lock().unwrap_or_else(|e| e.into_inner());
        let i = spares.iter().enumerate().filter(|(_, s)| s.1 >= len && s.1 <= 2 * len).min_by_key(|(_, s)| s.1)?.0;
        Some(spares.swap_remove(i))
    }
}

#[cfg(target_os = "linux")]
impl<T: Copy> Mapping<T> {
    /// Maps room for `len` values starting on a 2 MB boundary (over-mapping by one huge
    /// page to find it), advised for huge pages before anything touches it; `None` if the
    /// kernel refuses the mapping.
    fn new(len: usize) -> Option<Mapping<T>> {
        assert!(std::mem::align_of::<T>() <= HUGE_PAGE);
        let bytes = len.checked_mul(std::mem::size_of::<T>())?;
        let map_len = bytes.checked_add(HUGE_PAGE)?;
        let (base, map_len) = match Spare::take(map_len) {
            Some((base, kept_len)) => (base as *mut libc::c_void, kept_len),
            None => {
                // SAFETY: an anonymous private mapping at an address of the kernel's choosing.
                let base = unsafe { libc::mmap(std::ptr::null_mut(), map_len, libc::PROT_READ | libc::PROT_WRITE, libc::MAP_PRIVATE | libc::MAP_ANONYMOUS, -1, 0) };
                if base == libc::MAP_FAILED {
                    return None;
                }
                (base, map_len)
            }
        };
        let offset = (HUGE_PAGE - base as usize % HUGE_PAGE) % HUGE_PAGE;
        // SAFETY: `offset < HUGE_PAGE` and `bytes + HUGE_PAGE <= map_len`, so `data .. data
        // + bytes` lies inside the mapping.
        let data = unsafe { (base as *mut u8).add(offset) };
        // Advice only (the kernel may ignore it, e.g. with THP off): nothing to check. A
        // reused mapping is advised again over this array's range (the same pages or more).
        // SAFETY: the range lies inside the mapping and starts on a page boundary.
        unsafe { libc::madvise(data as *mut libc::c_void, bytes, libc::MADV_HUGEPAGE) };
        Some(Mapping { base, map_len, data: data as *mut T, len: 0 })
    }
}

impl<T: Copy> HugeArray<T> {
    /// The values of `values` (an exact-size iterator: its length is mapped up front).
    pub fn collect(values: impl ExactSizeIterator<Item = T>) -> HugeArray<T> {
        let len = values.len();
        #[cfg(target_os = "linux")]
        if len.saturating_mul(std::mem::size_of::<T>()) >= HUGE_PAGE {
            if let Some(mut m) = Mapping::<T>::new(len) {
                for v in values.take(len) {
                    // SAFETY: `m.len < len`, inside the room mapped for `len` values, and
                    // `data` is aligned for T (2 MB aligned).
                    unsafe { m.data.add(m.len).write(v) };
                    m.len += 1;
                }
                return HugeArray { data: m.data, len: m.len, storage: Storage::Mapped(m) };
            }
        }
        let v: Vec<T> = values.collect();
        HugeArray { data: v.as_ptr(), len: v.len(), storage: Storage::Heap(v) }
    }

    /// Whether the values live in a huge-page-advised mapping.
    pub fn mapped(&self) -> bool {
        !matches!(self.storage, Storage::Heap(_))
    }
}

impl<T: Copy> Deref for HugeArray<T> {
    type Target = [T];

    #[inline(always)]
    fn deref(&self) -> &[T] {
        // SAFETY: `data` holds `len` values written by `collect` (a Vec's pointer is
        // non-null and aligned even when empty), alive as long as `storage`.
        unsafe { std::slice::from_raw_parts(self.data, self.len) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Arrays below, at and above the threshold hold exactly what they were given, an
    /// iterator that claims more than it yields gives what it yielded, and on Linux the
    /// large ones are mapped on a 2 MB boundary.
    #[test]
    fn arrays_hold_their_values() {
        for len in [0usize, 1, 1000, HUGE_PAGE / 16 - 1, HUGE_PAGE / 16, 3 * HUGE_PAGE / 16 + 5] {
            let values: Vec<[u32; 4]> = (0..len as u32).map(|i| [i, i ^ 0x5555, i.wrapping_mul(2654435761), !i]).collect();
            let a = HugeArray::collect(values.iter().copied());
            assert_eq!(&a[..], &values[..], "len {len}");
            let large = len * 16 >= HUGE_PAGE;
            assert_eq!(a.mapped(), cfg!(target_os = "linux") && large, "len {len}");
            if a.mapped() {
                assert_eq!(a.as_ptr() as usize % HUGE_PAGE, 0);
            }
        }
    }

    /// A dropped array's mapping is reused by the next array of about its size, which holds
    /// its own values (not the old ones); a smaller array does not take a mapping twice its
    /// size. (21 MB: no other test here maps that much.)
    #[cfg(target_os = "linux")]
    #[test]
    fn a_dropped_mapping_is_reused() {
        let len = (21 << 20) / 8;
        let a = HugeArray::collect((0..len as u32).map(|i| i as u64 * 3));
        let at = a.as_ptr() as usize;
        drop(a);
        let small = HugeArray::collect((0..len as u32 / 3).map(u64::from));
        assert_ne!(small.as_ptr() as usize, at, "a third of the size takes a fresh mapping");
        let b = HugeArray::collect((0..len as u32).map(|i| i as u64 ^ 0xabcdef));
        assert_eq!(b.as_ptr() as usize, at, "the same size reuses the mapping");
        assert!(b.iter().copied().eq((0..len as u64).map(|i| i ^ 0xabcdef)));
    }

    /// An iterator whose `len` overstates what it yields: the array holds what came.
    #[test]
    fn a_short_iterator_gives_a_short_array() {
        struct Liar(u32);
        impl Iterator for Liar {
            type Item = u64;
            fn next(&mut self) -> Option<u64> {
                (self.0 < 1000).then(|| {
                    self.0 += 1;
                    self.0 as u64
                })
            }
        }
        impl ExactSizeIterator for Liar {
            fn len(&self) -> usize {
                1 << 20
            }
        }
        let a = HugeArray::collect(Liar(0));
        assert_eq!(a.len(), 1000);
        assert!(a.iter().copied().eq(1..=1000u64));
    }
}
