//! Checks shared by every binding that takes numpy arrays.

use numpy::{Element, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;

use crate::errors::InputError;

/// The rows of a C-contiguous [N, width] array as one flat slice, or an InputError naming `name`.
pub fn contiguous_rows<'a, T: Element>(
    name: &str,
    array: &'a PyReadonlyArray2<'_, T>,
    width: usize,
) -> PyResult<&'a [T]> {
    let shape = array.shape();
    if shape[1] != width {
        return Err(InputError::new_err(format!(
            "{name} must have shape [N, {width}], got {shape:?}"
        )));
    }
    array.as_slice().map_err(|_| {
        InputError::new_err(format!(
            "{name} must be C-contiguous (use numpy.ascontiguousarray)"
        ))
    })
}
