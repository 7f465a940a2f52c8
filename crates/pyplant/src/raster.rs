//! Bindings of the rasterizer: the forward passes of B scenes (a group's plants, or one
//! scene as a list of one) side by side on one pool, returning images and opaque states,
//! and the backward passes of those states.
//!
//! Each scene gets the bits it gets alone, and its own result: a scene whose input is bad
//! comes back as its exception, in its place in the list (not raised), and the other
//! scenes are computed.

use pyo3::prelude::*;
use pyo3::types::PyList;
use splat_core::raster::{self, BackwardJob, GradRequest};
use splat_core::threads::with_threads;

use crate::arrays::flat;
use crate::errors::{to_pyerr, InputError};
use crate::ints::threads_from;
use crate::raster_args::{raster_defaults, raster_options, upstream_views, ForwardArgs};
use crate::raster_results::{forward_dict, grads_dict, RasterState};
use crate::run_native;

/// The exception object of a scene's error (returned in its place, not raised).
fn scene_error(py: Python<'_>, err: PyErr) -> Py<PyAny> {
    err.into_value(py).into_any()
}

/// Forward rasterization of every scene in `scenes`, N Gaussians into C cameras each
/// (gsplat 1.5 classic semantics), the settings shared.
///
/// A scene is a dict: means, quats, scales, opacities, colors, viewmats, Ks, width, height
/// and optionally sh_degree and background (`ForwardArgs::from_scene`). `colors` is [N, D]
/// (used as is) or, with `sh_degree`, [N, K, 3] SH coefficients; it is ignored when
/// `render_color` is false. `background` [C, ch] (colours only) is blended behind the
/// features: render + background (1 - alpha). Returns a list, in the scenes' order, of
/// each scene's dict (`forward_dict`: render, alpha, radii, means2d, depths, n_visible,
/// n_intersections, profile, state) or of its exception. Integer arguments are checked in
/// `ints.rs`; a setting left at None takes `RasterOptions::default()`'s value
/// (`raster_defaults`).
#[pyfunction]
#[pyo3(signature = (
    scenes, *, near_plane=None, far_plane=None, eps2d=None, antialiased=None,
    render_color=true, render_depth=None, tile_size=None, footprint_sigma=None,
    tile_ellipse=None, t_min=None, simd=None, threads=None
))]
// One keyword per setting, as Python callers pass them.
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
        .map(|s| ForwardArgs::from_scene(&s, render_color))
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

/// Gradients of every forward state's inputs in `states`, from its dL/d(render)
/// [C, H, W, ch] and dL/d(alpha) [C, H, W] in `v_renders` and `v_alphas` (one each per
/// state; a v_alpha None: the alpha got no gradient), the gradient groups shared. Returns
/// a list, in the states' order, of each scene's dict (`grads_dict`: a group switched off
/// is None, means2d is always there) or of its exception.
#[pyfunction]
#[pyo3(signature = (
    states, v_renders, v_alphas, *, means=true, quats=true, scales=true, opacities=true,
    colors=true, threads=None
))]
// One keyword per gradient group, as Python callers pass them.
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
    m.add_class::<RasterState>()?;
    m.add_function(wrap_pyfunction!(raster_defaults, m)?)?;
    m.add_function(wrap_pyfunction!(rasterize_forward_many, m)?)?;
    m.add_function(wrap_pyfunction!(rasterize_backward_many, m)?)?;
    Ok(())
}
