//! Explicit thread counts for kernels.
//!
//! Kernels are written so that their output does not depend on the number of threads
//! (fixed work partitions, reductions in a fixed order). `with_threads` lets tests and
//! benchmarks prove that by running the same call on 1 and on N threads.

use std::sync::{Arc, Mutex, OnceLock};

use rayon::ThreadPool;

use crate::{CoreError, CoreResult};

/// Pools kept for reuse. A caller cycling through more distinct sizes than this builds
/// pools again, but never holds more than `MAX_POOLS * max_threads()` idle threads.
pub const MAX_POOLS: usize = 4;

/// Workers per call at most: 4 x the cores this process may use. Kernels give the same
/// output on any count, so more would only add threads, never speed.
pub fn max_threads() -> usize {
    4 * std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Runs `f` on a pool of `threads` workers, or on rayon's global pool when `None`.
///
/// Pools are built once per size and kept (the `MAX_POOLS` most recently used): a new pool
/// per call costs thread start-up, and fresh threads start with cold caches and empty
/// allocator heaps (~5 ms per forward at 100k Gaussians). `threads` must be in
/// 1..=`max_threads()`.
pub fn with_threads<R: Send>(
    threads: Option<usize>,
    f: impl FnOnce() -> CoreResult<R> + Send,
) -> CoreResult<R> {
    match threads {
        None => f(),
        Some(n) => pool(check_threads(n)?)?.install(f),
    }
}

/// `n` if it is a usable thread count, else an input error that says the range.
pub fn check_threads(n: usize) -> CoreResult<usize> {
    let max = max_threads();
    if n == 0 || n > max {
        return Err(CoreError::input(format!(
            "threads must be in 1..={max} (4 x the {} cores available), got {n}",
            max / 4
        )));
    }
    Ok(n)
}

/// Pools kept, by size, most recently used last.
type Pools = Vec<(usize, Arc<ThreadPool>)>;

static POOLS: OnceLock<Mutex<Pools>> = OnceLock::new();

fn pools() -> std::sync::MutexGuard<'static, Pools> {
    POOLS
        .get_or_init(Default::default)
        .lock()
        .unwrap_or_else(|e| e.into_inner())
}

fn pool(n: usize) -> CoreResult<Arc<ThreadPool>> {
    let mut pools = pools();
    if let Some(at) = pools.iter().position(|(size, _)| *size == n) {
        let entry = pools.remove(at);
        let p = entry.1.clone();
        pools.push(entry);
        return Ok(p);
    }
    let p = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .thread_name(move |i| format!("plantdreamer-{n}-{i}"))
            .build()
            .map_err(|e| CoreError::Internal(format!("cannot start a pool of {n} threads: {e}")))?,
    );
    if pools.len() == MAX_POOLS {
        // Dropping the last handle ends the pool's threads once their work is done.
        pools.remove(0);
    }
    pools.push((n, p.clone()));
    Ok(p)
}

/// Sizes of the pools kept, least recently used first.
pub fn kept_pool_sizes() -> Vec<usize> {
    pools().iter().map(|(size, _)| *size).collect()
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
    fn zero_and_too_many_threads_are_input_errors() {
        for n in [0, max_threads() + 1, usize::MAX] {
            let err = with_threads(Some(n), || Ok(())).unwrap_err();
            assert!(matches!(err, CoreError::Input(_)), "{err}");
            assert!(err.to_string().contains("threads must be in 1..="), "{err}");
        }
        assert!(with_threads(Some(max_threads()), || Ok(())).is_ok());
    }

    #[test]
    fn the_pool_cache_is_bounded() {
        for round in 0..3 {
            for n in 1..=(MAX_POOLS + 2).min(max_threads()) {
                let got = with_threads(Some(n), || Ok(rayon::current_num_threads())).unwrap();
                assert_eq!(got, n, "round {round}");
                assert!(kept_pool_sizes().len() <= MAX_POOLS);
            }
        }
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
