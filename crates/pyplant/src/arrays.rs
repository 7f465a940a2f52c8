//! Checks shared by every binding that takes numpy arrays.

use numpy::{
    PyArrayDyn, PyArrayMethods, PyReadonlyArray2, PyReadonlyArrayDyn, PyUntypedArrayMethods,
};
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

/// A C-contiguous float32 array with the given number of dimensions, borrowed (no copy).
pub(crate) fn f32_view<'py>(
    name: &str,
    obj: &Bound<'py, PyAny>,
    ndim: usize,
) -> PyResult<PyReadonlyArrayDyn<'py, f32>> {
    typed_view(name, obj, ndim, "float32")
}

/// A C-contiguous numpy array of `T` (`dtype`, named in the error) with the given number
/// of dimensions, borrowed (no copy).
pub(crate) fn typed_view<'py, T: numpy::Element>(
    name: &str,
    obj: &Bound<'py, PyAny>,
    ndim: usize,
    dtype: &str,
) -> PyResult<PyReadonlyArrayDyn<'py, T>> {
    let arr = obj
        .cast::<PyArrayDyn<T>>()
        .map_err(|_| InputError::new_err(format!("{name} must be a numpy array of {dtype}")))?;
    if arr.ndim() != ndim {
        return Err(InputError::new_err(format!(
            "{name} must have {ndim} dimensions, got shape {:?}",
            arr.shape()
        )));
    }
    // as_slice also accepts Fortran order, which would scramble the rows.
    if !arr.is_c_contiguous() {
        return Err(InputError::new_err(format!("{name} must be C-contiguous")));
    }
    Ok(arr.readonly())
}

/// The flat data of an array from `f32_view` or `typed_view`.
pub(crate) fn flat<'a, T: numpy::Element>(
    name: &str,
    view: &'a PyReadonlyArrayDyn<'_, T>,
) -> PyResult<&'a [T]> {
    view.as_slice()
        .map_err(|_| InputError::new_err(format!("{name} must be C-contiguous")))
}

/// A C-contiguous float32 array with the given number of dimensions, as its shape and a
/// flat copy (for data kept past the call: the caller may change its arrays).
pub(crate) fn f32_array(
    name: &str,
    obj: &Bound<'_, PyAny>,
    ndim: usize,
) -> PyResult<(Vec<usize>, Vec<f32>)> {
    let view = f32_view(name, obj, ndim)?;
    Ok((view.shape().to_vec(), flat(name, &view)?.to_vec()))
}

/// Checks `shape` against `want`, where None matches any size.
pub(crate) fn expect_shape(name: &str, shape: &[usize], want: &[Option<usize>]) -> PyResult<()> {
    let ok = shape.len() == want.len()
        && shape
            .iter()
            .zip(want)
            .all(|(s, w)| w.is_none_or(|w| *s == w));
    if ok {
        Ok(())
    } else {
        let want: Vec<String> = want
            .iter()
            .map(|w| w.map_or("*".to_string(), |v| v.to_string()))
            .collect();
        Err(InputError::new_err(format!(
            "{name} must have shape [{}], got {shape:?}",
            want.join(", ")
        )))
    }
}
