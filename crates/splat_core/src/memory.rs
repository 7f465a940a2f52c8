//! Allocations sized by the data, made fallibly.
//!
//! Rust aborts the process when an allocation fails (`handle_alloc_error`), which under a
//! memory limit (`ulimit -v`, as HPC schedulers set) ends the Python interpreter with no
//! error at all. The buffers whose size follows the input (images, per-Gaussian and
//! per-point arrays, PLY columns, tile lists) are reserved here instead, with
//! `try_reserve_exact`: a reservation that fails is `CoreError::OutOfMemory`, which the
//! bindings raise as `MemoryError` and the command line reports in one line. Small,
//! fixed-size working buffers still use the plain allocation.

use crate::{CoreError, CoreResult};

/// An empty vector with room for `len` values, reserved fallibly.
pub fn try_vec<T>(len: usize) -> CoreResult<Vec<T>> {
    let mut out = Vec::new();
    out.try_reserve_exact(len)
        .map_err(|_| CoreError::out_of_memory::<T>(len))?;
    Ok(out)
}

/// `len` copies of `value`, reserved fallibly.
pub fn try_filled<T: Clone>(len: usize, value: T) -> CoreResult<Vec<T>> {
    let mut out = try_vec(len)?;
    out.resize(len, value);
    Ok(out)
}

/// Room for `more` values after the end of `out`, reserved fallibly.
pub fn try_grow<T>(out: &mut Vec<T>, more: usize) -> CoreResult<()> {
    out.try_reserve(more)
        .map_err(|_| CoreError::out_of_memory::<T>(out.len().saturating_add(more)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_allocation_that_cannot_be_made_is_an_error_not_an_abort() {
        let err = try_vec::<u64>(usize::MAX / 4).unwrap_err();
        assert!(matches!(err, CoreError::OutOfMemory { .. }), "{err}");
        assert!(err.to_string().starts_with("out of memory"), "{err}");
        let err = try_filled(1usize << 62, 0u8).unwrap_err();
        assert!(err.to_string().contains("PiB"), "{err}");
        let mut v = vec![1u32];
        assert!(try_grow(&mut v, usize::MAX / 2).is_err());
    }

    #[test]
    fn what_fits_is_made() {
        assert_eq!(try_filled(3, 7u16).unwrap(), vec![7, 7, 7]);
        let v = try_vec::<f32>(10).unwrap();
        assert!(v.is_empty() && v.capacity() >= 10);
    }
}
