//! A hint to the processor to bring memory towards the cache before it is read: for lookups
//! scattered over tables of a few MB, named some work ahead of their use (a walk's room labels
//! one ray ahead, `prm::rooms`). Tried and not kept: the walks' next-bounce rows fetched one
//! row ahead (no change in their share of a precompute's samples, 17-19 % either way).

/// Asks the processor to fetch the cache line holding `items[i]`; nothing when `i` is out of
/// range or the target has no such hint. Reads nothing the program sees.
#[inline]
pub fn prefetch<T>(items: &[T], i: usize) {
    #[cfg(target_arch = "x86_64")]
    if i < items.len() {
        let p = items[i..].as_ptr().cast::<i8>();
        // SAFETY: a prefetch is a hint: it reads nothing the program sees and does not fault,
        // whatever the address (here one inside `items`).
        unsafe { std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(p) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (items, i);
}
