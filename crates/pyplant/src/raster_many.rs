//! Bindings of the many-scene rasterizer calls (a group's plants in one call): the forward
//! passes of B scenes, or their backward passes, side by side on one pool.
//!
//! Each scene gets the bits of its own `rasterize_forward` / `rasterize_backward` call and
//! its own result: a scene whose input is bad comes back as its exception, in its place in
//! the list (not raised), and the other scenes are computed.

use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use splat_core::raster::{self, BackwardJob, GradRequest};
use splat_core::threads::with_threads;

use crate::errors::{to_pyerr, InputError};
use crate::ints::threads_from;
use crate::raster::{
    flat, forward_dict, grads_dict, raster_options, upstream_views, ForwardArgs, RasterState,
};
use crate::run_native;

/// The exception object of a scene's error (returned in its place, not raised).
fn scene_error(py: Python<'_>, err: PyErr) -> Py<PyAny> {
    err.into_value(py).into_any()
}

/// One scene's `rasterize_forward` arguments from its dict: means, quats, scales, opacities,
/// colors, viewmats, Ks, width, height and (optional) sh_degree and background.
fn scene_args(scene: &Bound<'_, PyAny>, render_color: bool) -> PyResult<ForwardArgs> {
    let d = scene.cast::<PyDict>().map_err(|_| {
        InputError::new_err("each scene must be a dict of rasterize_forward's arrays")
    })?;
    let get = |key: &str| -> PyResult<Bound<'_, PyAny>> {
        d.get_item(key)?
            .ok_or_else(|| InputError::new_err(format!("the scene has no {key:?}")))
    };
    let sh_degree = d.get_item("sh_degree")?;
    let background = d.get_item("background")?;
    ForwardArgs::new(
        &get("means")?,
        &get("quats")?,
        &get("scales")?,
        &get("opacities")?,
        &get("colors")?,
        &get("viewmats")?,
        &get("Ks")?,
        &get("width")?,
        &get("height")?,
        sh_degree.as_ref(),
        render_color,
    )?
    .with_background(background.as_ref())
}

/// `rasterize_forward` of every scene in `scenes` (dicts of its positional arrays and
/// sizes, and optionally sh_degree and background), the settings shared. Returns a list, in the scenes'
/// order, of `rasterize_forward`'s dict or of the scene's exception.
#[pyfunction]
#[pyo3(signature = (
    scenes, *, near_plane=None, far_plane=None, eps2d=None, antialiased=None,
    render_color=true, render_depth=None, tile_size=None, footprint_sigma=None,
    tile_ellipse=None, t_min=None, simd=None, threads=None
))]
// One keyword per setting, as in rasterize_forward.
#[allow(clippy::too_many_arguments)]
fn rasterize_forward_many<'py>(
    py: Python<'py>,
    scenes: &Bound<'py, PyList>,
    near_plane: Option<f32>,
    far_plane: Option<f32>,
    eps2d: Option<f32>,
    antialiased: Option<bool>,
    render_color: bool,
    render_depth: Option<bool>,
    tile_size: Option<&Bound<'py, PyAny>>,
    footprint_sigma: Option<f32>,
    tile_ellipse: Option<bool>,
    t_min: Option<f32>,
    simd: Option<bool>,
    threads: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyList>> {
    let opts = raster_options(
        near_plane,
        far_plane,
        eps2d,
        antialiased,
        render_depth,
        tile_size,
        footprint_sigma,
        tile_ellipse,
        t_min,
        simd,
    )?;
    let threads = threads_from(threads)?;
    let parsed: Vec<PyResult<ForwardArgs>> = scenes
        .iter()
        .map(|s| scene_args(&s, render_color))
        .collect();
    let sizes: Vec<(usize, usize)> = parsed
        .iter()
        .map(|a| a.as_ref().map_or((0, 0), |a| (a.c, a.n)))
        .collect();
    let done = on_ok(parsed, |good| {
        let rendered = run_native(py, || {
            with_threads(threads, || {
                let jobs = good.into_iter().map(ForwardArgs::job).collect();
                Ok(on_ok(jobs, |ok| raster::forward_many(ok, opts)))
            })
        });
        match rendered {
            Ok(results) => results.into_iter().map(|r| r.map_err(to_pyerr)).collect(),
            Err(e) => vec![Err(e)], // a panic: the whole call failed
        }
    });
    if done.len() != sizes.len() {
        let e = done.into_iter().find_map(Result::err);
        return Err(e.unwrap_or_else(|| InputError::new_err("internal error: lost scenes")));
    }
    let items = done
        .into_iter()
        .zip(sizes)
        .map(|(r, (c, n))| match r {
            Ok((out, state)) => Ok(forward_dict(py, out, state, c, n)?.into_any().unbind()),
            Err(e) => Ok(scene_error(py, e)),
        })
        .collect::<PyResult<Vec<Py<PyAny>>>>()?;
    PyList::new(py, items)
}

/// `f` applied to the items that are Ok (one result per item, in order), and the results
/// put back in the items' order beside the items' own errors.
fn on_ok<T, U, E>(
    items: Vec<Result<T, E>>,
    f: impl FnOnce(Vec<T>) -> Vec<Result<U, E>>,
) -> Vec<Result<U, E>> {
    let mut errors = Vec::with_capacity(items.len());
    let mut ok = Vec::new();
    for item in items {
        match item {
            Ok(v) => {
                ok.push(v);
                errors.push(None);
            }
            Err(e) => errors.push(Some(e)),
        }
    }
    let expected = ok.len();
    let results = f(ok);
    if results.len() != expected {
        return results; // f failed as a whole; the caller sees the count differ
    }
    let mut results = results.into_iter();
    errors
        .into_iter()
        .map(|e| match e {
            Some(e) => Err(e),
            None => results.next().expect("one result per item"),
        })
        .collect()
}

/// `rasterize_backward` of every forward state in `states`, with its dL/d(render) and
/// dL/d(alpha) from `v_renders` and `v_alphas` (one each per state; a v_alpha may be
/// None), the gradient groups shared. Returns a list, in the states' order, of
/// `rasterize_backward`'s dict or of the scene's exception.
#[pyfunction]
#[pyo3(signature = (
    states, v_renders, v_alphas, *, means=true, quats=true, scales=true, opacities=true,
    colors=true, threads=None
))]
// One keyword per gradient group, as in rasterize_backward.
#[allow(clippy::too_many_arguments)]
fn rasterize_backward_many<'py>(
    py: Python<'py>,
    states: Vec<Bound<'py, RasterState>>,
    v_renders: Vec<Bound<'py, PyAny>>,
    v_alphas: Vec<Bound<'py, PyAny>>,
    means: bool,
    quats: bool,
    scales: bool,
    opacities: bool,
    colors: bool,
    threads: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyList>> {
    let threads = threads_from(threads)?;
    if v_renders.len() != states.len() || v_alphas.len() != states.len() {
        return Err(InputError::new_err(format!(
            "one v_render and one v_alpha per state: {} states, {} v_renders, {} v_alphas",
            states.len(),
            v_renders.len(),
            v_alphas.len()
        )));
    }
    let inner: Vec<_> = states.iter().map(|s| &s.get().inner).collect();
    // Read in place: the backward keeps nothing of them.
    let views: Vec<PyResult<_>> = inner
        .iter()
        .zip(v_renders.iter().zip(&v_alphas))
        .map(|(st, (vr, va))| upstream_views(st, vr, Some(va)))
        .collect();
    let slices: Vec<PyResult<BackwardJob<'_>>> = views
        .iter()
        .zip(&inner)
        .map(|(v, st)| match v {
            Ok((vr, va)) => Ok(BackwardJob {
                state: st,
                v_render: flat("v_render", vr)?,
                v_alpha: va.as_ref().map(|v| flat("v_alpha", v)).transpose()?,
            }),
            Err(e) => Err(e.clone_ref(py)),
        })
        .collect();
    let want = GradRequest {
        means,
        quats,
        scales,
        opacities,
        colors,
    };
    let done = on_ok(slices, |jobs| {
        let grads = run_native(py, || {
            with_threads(threads, || Ok(raster::backward_many(&jobs, want)))
        });
        match grads {
            Ok(results) => results.into_iter().map(|r| r.map_err(to_pyerr)).collect(),
            Err(e) => vec![Err(e)],
        }
    });
    if done.len() != inner.len() {
        let e = done.into_iter().find_map(Result::err);
        return Err(e.unwrap_or_else(|| InputError::new_err("internal error: lost scenes")));
    }
    let items = done
        .into_iter()
        .zip(&inner)
        .map(|(r, st)| match r {
            Ok(g) => Ok(grads_dict(py, g, st)?.into_any().unbind()),
            Err(e) => Ok(scene_error(py, e)),
        })
        .collect::<PyResult<Vec<Py<PyAny>>>>()?;
    PyList::new(py, items)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(rasterize_forward_many, m)?)?;
    m.add_function(wrap_pyfunction!(rasterize_backward_many, m)?)?;
    Ok(())
}
