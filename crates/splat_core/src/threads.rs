//! Explicit thread counts for kernels.
//!
//! Kernels are written so that their output does not depend on the number of threads
//! (fixed work partitions, reductions in a fixed order). `with_threads` lets tests and
//! benchmarks prove that by running the same call on 1 and on N threads.

use std::sync::{Arc, Mutex, OnceLock};

use rayon::ThreadPool;

use crate::{CoreError, CoreResult};

/// Runs `f` on a pool of `threads` workers, or on rayon's global pool when `None`.
///
/// Pools are built once per size and kept: a new pool per call costs thread start-up, and
/// fresh threads start with cold caches and empty allocator heaps (~5 ms per forward at
/// 100k Gaussians).
pub fn with_threads<R: Send>(
    threads: Option<usize>,
    f: impl FnOnce() -> CoreResult<R> + Send,
) -> CoreResult<R> {
    match threads {
        None => f(),
        Some(0) => Err(CoreError::input("threads must be at least 1")),
        Some(n) => pool(n)?.install(f),
    }
}

/// Pools built so far, by size.
type Pools = Mutex<Vec<(usize, Arc<ThreadPool>)>>;

fn pool(n: usize) -> CoreResult<Arc<ThreadPool>> {
    static POOLS: OnceLock<Pools> = OnceLock::new();
    let mut pools = POOLS
        .get_or_init(Default::default)
        .lock()
        .unwrap_or_else(|e| e.into_inner());
    if let Some((_, p)) = pools.iter().find(|(size, _)| *size == n) {
        return Ok(p.clone());
    }
    let p = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .thread_name(move |i| format!("plantdreamer-{n}-{i}"))
            .build()
            .map_err(|e| CoreError::Internal(format!("cannot start a pool of {n} threads: {e}")))?,
    );
    pools.push((n, p.clone()));
    Ok(p)
}

/// Number of workers in rayon's global pool (set with `RAYON_NUM_THREADS`).
pub fn default_threads() -> usize {
    rayon::current_num_threads()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rayon::prelude::*;

    #[test]
    fn pool_has_requested_size() {
        let n = with_threads(Some(3), || Ok(rayon::current_num_threads())).unwrap();
        assert_eq!(n, 3);
    }

    #[test]
    fn zero_threads_is_an_input_error() {
        assert!(matches!(
            with_threads(Some(0), || Ok(())),
            Err(CoreError::Input(_))
        ));
    }

    #[test]
    fn fixed_order_sum_is_thread_independent() {
        let xs: Vec<f32> = (0..10_000).map(|i| (i as f32 * 0.37).sin() * 1e3).collect();
        let sum = |t| {
            with_threads(Some(t), || {
                // Fixed chunking, then a sequential reduction of the partials.
                let partials: Vec<f32> = xs.par_chunks(256).map(|c| c.iter().sum()).collect();
                Ok(partials.iter().sum::<f32>())
            })
            .unwrap()
        };
        assert_eq!(sum(1).to_bits(), sum(2).to_bits());
    }
}
