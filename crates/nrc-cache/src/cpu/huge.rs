//! Large buffers backed by transparent huge pages where the OS allows it.
//!
//! The hash table is read and updated at random: with 4 KiB pages nearly every access to a
//! fine level misses the TLB as well as the cache. Linux backs a region advised with
//! `MADV_HUGEPAGE` by 2 MiB pages when it is first touched (the default THP mode here is
//! `madvise`), so the buffers are advised before they are filled.

/// A vector of `n` copies of `value`, advised for huge pages when it is large (Linux).
pub fn huge_vec<T: Copy>(n: usize, value: T) -> Vec<T> {
    let mut v = huge_empty(n);
    v.resize(n, value);
    v
}

/// An empty vector with room for `n` elements, advised for huge pages when it is large
/// (Linux): for callers that write every element themselves, in parallel, through
/// [`Vec::spare_capacity_mut`].
pub fn huge_empty<T>(n: usize) -> Vec<T> {
    let mut v: Vec<T> = Vec::with_capacity(n);
    #[cfg(target_os = "linux")]
    {
        const HUGE: usize = 2 << 20;
        let bytes = n * std::mem::size_of::<T>();
        if bytes >= 2 * HUGE {
            let p = v.as_mut_ptr() as usize;
            let start = p.next_multiple_of(HUGE);
            let end = (p + bytes) / HUGE * HUGE;
            if end > start {
                // SAFETY: the range lies inside this vector's allocation; the advice only
                // changes how its pages are backed, never their contents.
                unsafe {
                    libc::madvise(start as *mut libc::c_void, end - start, libc::MADV_HUGEPAGE);
                }
            }
        }
    }
    v
}
