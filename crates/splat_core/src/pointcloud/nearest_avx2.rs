//! The distance-only search (`nearest::run_leaves`) compiled for AVX2: the same code,
//! inlined into a function with the feature enabled, so its distance, mask and network
//! loops use 4-lane instructions. No fused multiply-add is enabled, so every value is
//! rounded as in the portable instance. The only unsafe code is the call into the
//! `#[target_feature]` function after `is_x86_feature_detected!("avx2")`.
#![allow(unsafe_code)]

use super::kdtree::KdTree;

pub(super) fn run_leaves<const P: usize, R>(
    tree: &KdTree,
    k: usize,
    leaves: &[usize],
    f: &impl Fn(usize, &[f64]) -> R,
    out: &mut Vec<R>,
) {
    debug_assert!(std::arch::is_x86_feature_detected!("avx2"));
    // SAFETY: `nearest::run_leaves_dispatch` calls this only after detecting AVX2.
    unsafe { run_leaves_avx2::<P, R>(tree, k, leaves, f, out) }
}

#[target_feature(enable = "avx2")]
unsafe fn run_leaves_avx2<const P: usize, R>(
    tree: &KdTree,
    k: usize,
    leaves: &[usize],
    f: &impl Fn(usize, &[f64]) -> R,
    out: &mut Vec<R>,
) {
    super::nearest::run_leaves::<P, R>(tree, k, leaves, f, out);
}
