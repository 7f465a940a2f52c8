//! Checks shared by every binding that takes numpy arrays.

use numpy::{PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;

use crate::errors::InputError;

/// "shape [..] of dtype" of an array-like, or its type name, for error messages.
pub fn describe(obj: &Bound<'_, PyAny>) -> String {
    match (obj.getattr("shape"), obj.getattr("dtype")) {
        (Ok(shape), Ok(dtype)) => format!("shape {shape} of {dtype}"),
        _ => obj
            .get_type()
            .name()
            .map(|n| n.to_string())
            .unwrap_or_default(),
    }
}

/// Checks a float array of shape [N, width]: dtype, shape, contiguity. None when the dtype
/// is not `T` (the caller may try another precision or name the accepted ones).
pub fn float_rows<'py, T: numpy::Element>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    width: usize,
) -> Option<PyResult<PyReadonlyArray2<'py, T>>> {
    let arr = obj.extract::<PyReadonlyArray2<'py, T>>().ok()?;
    if arr.shape()[1] != width {
        return Some(Err(InputError::new_err(format!(
            "{name} must have shape [N, {width}], got {}",
            describe(obj)
        ))));
    }
    if !arr.is_c_contiguous() {
        return Some(Err(InputError::new_err(format!(
            "{name} must be C-contiguous (use numpy.ascontiguousarray)"
        ))));
    }
    Some(Ok(arr))
}
