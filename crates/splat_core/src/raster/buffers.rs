//! Large per-call buffers, filled by every thread of the pool.
//!
//! `vec![v; n]` fills on the calling thread alone (a memset of reused memory, or page
//! faults on fresh memory at first touch); the forward's outputs and tile state are
//! several megabytes per call, which left the other threads idle meanwhile.

use rayon::prelude::*;

/// `n` copies of `v`, written in parallel.
pub(super) fn filled<T: Copy + Send + Sync>(n: usize, v: T) -> Vec<T> {
    let mut out = Vec::new();
    rayon::iter::repeat_n(v, n).collect_into_vec(&mut out);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn filled_is_n_copies() {
        assert_eq!(filled(5, 1.5f32), vec![1.5f32; 5]);
        assert!(filled(0, 0u32).is_empty());
        let big = filled(1 << 20, 7u32);
        assert_eq!(big.len(), 1 << 20);
        assert!(big.iter().all(|&x| x == 7));
    }
}
