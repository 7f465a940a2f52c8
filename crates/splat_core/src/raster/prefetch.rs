//! A cache-line prefetch hint, the one piece of unsafe code the tile walks need.
#![allow(unsafe_code)]

/// Asks for the cache line holding `v`; a no-op off x86-64.
#[inline(always)]
pub(super) fn prefetch<T>(v: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: SSE is part of x86-64; a prefetch is a hint that neither reads memory nor
    // faults.
    unsafe {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        _mm_prefetch::<_MM_HINT_T0>((v as *const T).cast());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = v;
}
