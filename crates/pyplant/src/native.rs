//! Running core work from Python: without the GIL, and with panics turned into errors.

use std::panic::{catch_unwind, AssertUnwindSafe};

use pyo3::prelude::*;
use splat_core::CoreResult;

use crate::errors::{to_pyerr, PlantDreamerError};

/// Runs `f` with the GIL released so torch and other Python threads keep running.
///
/// A panic inside the core (a bug) becomes `PlantDreamerError` instead of crashing the
/// interpreter or surfacing pyo3's `PanicException`.
pub fn run_native<T: Send>(
    py: Python<'_>,
    f: impl FnOnce() -> CoreResult<T> + Send,
) -> PyResult<T> {
    match py.detach(|| catch_unwind(AssertUnwindSafe(f))) {
        Ok(result) => result.map_err(to_pyerr),
        Err(payload) => {
            let what = payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".to_string());
            Err(PlantDreamerError::new_err(format!(
                "internal error in the native core (please report it): {what}"
            )))
        }
    }
}
