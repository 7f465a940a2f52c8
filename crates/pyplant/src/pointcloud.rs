//! Bindings of `splat_core::pointcloud`: kNN, statistical outlier removal, voxel grid.
//!
//! Points are C-contiguous float32 or float64 arrays of shape [N, 3]; outputs keep the
//! input precision. `threads` runs a call on an explicit pool (None: rayon's global pool).

use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray2};
use pyo3::prelude::*;
use splat_core::pointcloud as pc;
use splat_core::threads::with_threads;

use crate::arrays::{describe, float_rows};
use crate::errors::InputError;
use crate::ints::{threads_from, usize_from};
use crate::run_native;

/// A borrowed [N, 3] point array of either precision.
pub enum Points<'py> {
    F32(PyReadonlyArray2<'py, f32>),
    F64(PyReadonlyArray2<'py, f64>),
}

pub fn points_arg<'py>(obj: &Bound<'py, PyAny>, name: &str) -> PyResult<Points<'py>> {
    if let Some(r) = float_rows::<f32>(obj, name, 3) {
        return r.map(Points::F32);
    }
    if let Some(r) = float_rows::<f64>(obj, name, 3) {
        return r.map(Points::F64);
    }
    Err(InputError::new_err(format!(
        "{name} must be a float32 or float64 array of shape [N, 3], got {}",
        describe(obj)
    )))
}

fn colors_arg<'py>(
    obj: Option<&Bound<'py, PyAny>>,
) -> PyResult<Option<PyReadonlyArray2<'py, f32>>> {
    let Some(obj) = obj.filter(|o| !o.is_none()) else {
        return Ok(None);
    };
    float_rows::<f32>(obj, "colors", 3)
        .unwrap_or_else(|| {
            Err(InputError::new_err(format!(
                "colors must be a float32 array of shape [N, 3], got {}",
                describe(obj)
            )))
        })
        .map(Some)
}

fn slice<'a, T: numpy::Element>(arr: &'a PyReadonlyArray2<'_, T>) -> PyResult<&'a [T]> {
    arr.as_slice()
        .map_err(|e| InputError::new_err(e.to_string()))
}

/// Calls `$body` with `$p` bound to the points slice of whichever precision.
macro_rules! with_points {
    ($points:expr, $p:ident => $body:expr) => {
        match &$points {
            Points::F32(a) => {
                let $p = slice(a)?;
                $body
            }
            Points::F64(a) => {
                let $p = slice(a)?;
                $body
            }
        }
    };
}

fn rows<'py, T: numpy::Element>(
    py: Python<'py>,
    data: Vec<T>,
    width: usize,
) -> PyResult<Bound<'py, PyAny>> {
    let n = data.len() / width.max(1);
    Ok(PyArray1::from_vec(py, data).reshape([n, width])?.into_any())
}

/// f64 voxel means back to the input precision.
fn points_out<'py>(
    py: Python<'py>,
    like: &Points<'_>,
    data: Vec<f64>,
) -> PyResult<Bound<'py, PyAny>> {
    match like {
        Points::F32(_) => rows(
            py,
            data.into_iter().map(|v| v as f32).collect::<Vec<f32>>(),
            3,
        ),
        Points::F64(_) => rows(py, data, 3),
    }
}

#[pyfunction]
#[pyo3(signature = (points, nb_neighbors, std_ratio, threads=None))]
fn remove_statistical_outliers<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    nb_neighbors: &Bound<'py, PyAny>,
    std_ratio: f64,
    threads: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArray1<i64>>> {
    let nb_neighbors = usize_from(nb_neighbors, "nb_neighbors", 1)?;
    let threads = threads_from(threads)?;
    let points = points_arg(points, "points")?;
    let kept = with_points!(points, p => run_native(py, || with_threads(threads, || pc::remove_statistical_outliers(p, nb_neighbors, std_ratio))))?;
    Ok(PyArray1::from_vec(py, kept))
}

#[pyfunction]
#[pyo3(signature = (points, voxel_size, colors=None, threads=None))]
fn voxel_downsample<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    voxel_size: f64,
    colors: Option<&Bound<'py, PyAny>>,
    threads: Option<&Bound<'py, PyAny>>,
) -> PyResult<(Bound<'py, PyAny>, Option<Bound<'py, PyAny>>)> {
    let threads = threads_from(threads)?;
    let pts = points_arg(points, "points")?;
    let colors = colors_arg(colors)?;
    let c = colors.as_ref().map(slice).transpose()?;
    let out = with_points!(pts, p => run_native(py, || with_threads(threads, || pc::voxel_downsample(p, voxel_size, c))))?;
    Ok((
        points_out(py, &pts, out.points)?,
        out.colors.map(|c| rows(py, c, 3)).transpose()?,
    ))
}

#[pyfunction]
#[pyo3(signature = (points, target, colors=None, tolerance=0.05, threads=None))]
fn downsample_to_count<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    target: &Bound<'py, PyAny>,
    colors: Option<&Bound<'py, PyAny>>,
    tolerance: f64,
    threads: Option<&Bound<'py, PyAny>>,
) -> PyResult<(Bound<'py, PyAny>, Option<Bound<'py, PyAny>>, f64)> {
    let target = usize_from(target, "target", 1)?;
    let threads = threads_from(threads)?;
    let pts = points_arg(points, "points")?;
    let colors = colors_arg(colors)?;
    let c = colors.as_ref().map(slice).transpose()?;
    let r = with_points!(pts, p => run_native(py, || with_threads(threads, || pc::downsample_to_count(p, target, c, tolerance))))?;
    Ok((
        points_out(py, &pts, r.output.points)?,
        r.output.colors.map(|c| rows(py, c, 3)).transpose()?,
        r.voxel_size,
    ))
}

#[pyfunction]
#[pyo3(signature = (points, k, threads=None))]
fn knn<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    k: &Bound<'py, PyAny>,
    threads: Option<&Bound<'py, PyAny>>,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    let k = usize_from(k, "k", 1)?;
    let threads = threads_from(threads)?;
    let pts = points_arg(points, "points")?;
    let (ids, d) =
        with_points!(pts, p => run_native(py, || with_threads(threads, || pc::knn(p, k))))?;
    Ok((rows(py, ids, k)?, rows(py, d, k)?))
}

#[pyfunction]
#[pyo3(signature = (points, k, threads=None))]
fn knn_mean_distance<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    k: &Bound<'py, PyAny>,
    threads: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArray1<f32>>> {
    let k = usize_from(k, "k", 1)?;
    let threads = threads_from(threads)?;
    let pts = points_arg(points, "points")?;
    let m = with_points!(pts, p => run_native(py, || with_threads(threads, || pc::knn_mean_distance(p, k))))?;
    Ok(PyArray1::from_vec(py, m))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(remove_statistical_outliers, m)?)?;
    m.add_function(wrap_pyfunction!(voxel_downsample, m)?)?;
    m.add_function(wrap_pyfunction!(downsample_to_count, m)?)?;
    m.add_function(wrap_pyfunction!(knn, m)?)?;
    m.add_function(wrap_pyfunction!(knn_mean_distance, m)?)?;
    Ok(())
}
