//! Integer arguments. Every width, height, count, k and thread count that reaches the core
//! is taken as any Python int and checked here, so a negative, huge or non-integer value is
//! an `InputError` that states the accepted range, never pyo3's `OverflowError` or a
//! silently truncated float.

use pyo3::exceptions::PyOverflowError;
use pyo3::prelude::*;

use crate::errors::{to_pyerr, InputError};

/// `obj` as an integer in `min..=max`.
pub fn int_in(obj: &Bound<'_, PyAny>, name: &str, min: i64, max: i64) -> PyResult<i64> {
    let range = || {
        if max == i64::MAX {
            format!("an integer >= {min}")
        } else {
            format!("an integer in {min}..={max}")
        }
    };
    match obj.extract::<i64>() {
        Ok(v) if (min..=max).contains(&v) => Ok(v),
        Ok(v) => Err(InputError::new_err(format!(
            "{name} must be {}, got {v}",
            range()
        ))),
        Err(e) if e.is_instance_of::<PyOverflowError>(obj.py()) => Err(InputError::new_err(
            format!("{name} must be {}, got {obj}", range()),
        )),
        Err(_) => Err(InputError::new_err(format!(
            "{name} must be {}, got {} {}",
            range(),
            obj.get_type()
                .name()
                .map(|n| n.to_string())
                .unwrap_or_default(),
            obj.repr().map(|r| r.to_string()).unwrap_or_default()
        ))),
    }
}

/// `obj` as a count or size of at least `min` (64-bit platforms: usize holds any i64).
pub fn usize_from(obj: &Bound<'_, PyAny>, name: &str, min: usize) -> PyResult<usize> {
    let v = int_in(obj, name, min as i64, i64::MAX)?;
    usize::try_from(v).map_err(|_| InputError::new_err(format!("{name} is too large, got {v}")))
}

/// `obj` as a u32 (image sizes, tile sizes) of at least `min`.
pub fn u32_from(obj: &Bound<'_, PyAny>, name: &str, min: u32) -> PyResult<u32> {
    let v = int_in(obj, name, i64::from(min), i64::from(u32::MAX))?;
    u32::try_from(v).map_err(|_| InputError::new_err(format!("{name} is too large, got {v}")))
}

/// The `threads=` argument: None (the global pool) or 1..=`max_threads()`.
pub fn threads_from(obj: Option<&Bound<'_, PyAny>>) -> PyResult<Option<usize>> {
    let Some(obj) = obj.filter(|o| !o.is_none()) else {
        return Ok(None);
    };
    // The core states the upper bound (4 x the cores available).
    let n = usize_from(obj, "threads", 1)?;
    splat_core::threads::check_threads(n)
        .map(Some)
        .map_err(to_pyerr)
}
