//! Large per-call buffers, filled by every thread of the pool.
//!
//! `vec![v; n]` fills on the calling thread alone (a memset of reused memory, or page
//! faults on fresh memory at first touch); the forward's outputs and tile state are
//! several megabytes per call, which left the other threads idle meanwhile.

use rayon::prelude::*;

use crate::memory::try_vec;
use crate::CoreResult;

/// `n` copies of `v`, written in parallel; reserved fallibly (`memory.rs`).
pub(super) fn filled<T: Copy + Send + Sync>(n: usize, v: T) -> CoreResult<Vec<T>> {
    let mut out = try_vec(n)?;
    rayon::iter::repeat_n(v, n).collect_into_vec(&mut out);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn filled_is_n_copies() {
        assert_eq!(filled(5, 1.5f32).unwrap(), vec![1.5f32; 5]);
        assert!(filled(0, 0u32).unwrap().is_empty());
        assert!(filled(usize::MAX / 8, 0u64).is_err());
        let big = filled(1 << 20, 7u32).unwrap();
        assert_eq!(big.len(), 1 << 20);
        assert!(big.iter().all(|&x| x == 7));
    }
}
