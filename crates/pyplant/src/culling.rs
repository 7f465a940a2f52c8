//! Bindings of `splat_core::culling`.

use numpy::{IntoPyArray, PyArray1};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::{describe, float_rows};
use crate::errors::InputError;
use crate::run_native;

/// Boolean mask of Gaussians whose volume exceeds mean + c * std, and the statistics used.
#[pyfunction]
#[pyo3(signature = (log_scales, c = 3.0))]
fn large_gaussian_mask<'py>(
    py: Python<'py>,
    log_scales: &Bound<'py, PyAny>,
    c: f64,
) -> PyResult<(Bound<'py, PyArray1<bool>>, Bound<'py, PyDict>)> {
    let array = float_rows::<f32>(log_scales, "log_scales", 3).unwrap_or_else(|| {
        Err(InputError::new_err(format!(
            "log_scales must be a float32 array of shape [N, 3], got {}",
            describe(log_scales)
        )))
    })?;
    let s = array
        .as_slice()
        .map_err(|e| InputError::new_err(e.to_string()))?;
    let (mask, stats) = run_native(py, || splat_core::culling::large_gaussians(s, c))?;
    let d = PyDict::new(py);
    d.set_item("mean", stats.mean)?;
    d.set_item("std", stats.std)?;
    d.set_item("threshold", stats.threshold)?;
    d.set_item("culled", stats.culled)?;
    Ok((mask.into_pyarray(py), d))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(large_gaussian_mask, m)?)?;
    Ok(())
}
