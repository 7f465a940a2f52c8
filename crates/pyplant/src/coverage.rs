//! Binding of `splat_core::raster::group_coverage`: each group's silhouette alone in one
//! camera of a forward pass, counted against a label map (a view's leaf occlusion).

use numpy::{IntoPyArray, PyArray1, PyUntypedArrayMethods};
use pyo3::prelude::*;
use splat_core::raster::{self, LabelMap};
use splat_core::threads::with_threads;

use crate::arrays::{flat, typed_view};
use crate::errors::InputError;
use crate::ints::{threads_from, u32_from, usize_from};
use crate::raster_results::RasterState;
use crate::run_native;

/// (alone, visible): pixels per group.
type Counts<'py> = (Bound<'py, PyArray1<i64>>, Bound<'py, PyArray1<i64>>);

/// Pixels of each group's silhouette (alpha >= `alpha_threshold` when its Gaussians are
/// rendered alone, with the pass's projection) and of those the label map gives it.
///
/// `state`: a `rasterize_forward_many` scene's state; `camera`: which of its cameras;
/// `groups` int32 [N]: each of its Gaussians' group, 0..G, or -1 (none); `labels` int32
/// [H, W]: each pixel's label; `group_labels` int32 [G]: each group's label;
/// `tile_size`: of the groups' tile lists (None: the pass's; any gives the same counts).
/// Returns (alone, visible), int64 [G] each.
#[pyfunction]
#[pyo3(signature = (
    state, groups, labels, group_labels, *, alpha_threshold, camera=None, tile_size=None,
    threads=None
))]
// One keyword per setting, as Python callers pass them.
#[allow(clippy::too_many_arguments)]
fn group_coverage<'py>(
    py: Python<'py>,
    state: Bound<'py, RasterState>,
    groups: &Bound<'py, PyAny>,
    labels: &Bound<'py, PyAny>,
    group_labels: &Bound<'py, PyAny>,
    alpha_threshold: f32,
    camera: Option<&Bound<'py, PyAny>>,
    tile_size: Option<&Bound<'py, PyAny>>,
    threads: Option<&Bound<'py, PyAny>>,
) -> PyResult<Counts<'py>> {
    let threads = threads_from(threads)?;
    let camera = camera.map_or(Ok(0), |c| usize_from(c, "camera", 0))?;
    let inner = &state.get().inner;
    let tile_size = tile_size.map_or(Ok(inner.opts.tile_size), |t| u32_from(t, "tile_size", 0))?;
    let group_view = typed_view::<i32>("groups", groups, 1, "int32")?;
    let label_view = typed_view::<i32>("labels", labels, 2, "int32")?;
    let names_view = typed_view::<i32>("group_labels", group_labels, 1, "int32")?;
    let shape = label_view.shape().to_vec();
    if shape != [inner.height as usize, inner.width as usize] {
        return Err(InputError::new_err(format!(
            "labels must have shape [{}, {}] (the image), got {shape:?}",
            inner.height, inner.width
        )));
    }
    let groups = flat("groups", &group_view)?;
    let map = LabelMap {
        labels: flat("labels", &label_view)?,
        group_labels: flat("group_labels", &names_view)?,
    };
    let counted = run_native(py, || {
        with_threads(threads, || {
            raster::group_coverage(inner, camera, groups, tile_size, alpha_threshold, map)
        })
    })?;
    let as_i64 = |v: Vec<u64>| v.into_iter().map(|x| x as i64).collect::<Vec<_>>();
    Ok((
        as_i64(counted.alone).into_pyarray(py),
        as_i64(counted.visible).into_pyarray(py),
    ))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(group_coverage, m)?)?;
    Ok(())
}
