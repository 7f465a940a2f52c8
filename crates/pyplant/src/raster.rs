//! Bindings of the rasterizer: forward (returns images + an opaque state) and backward.

use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use splat_core::raster::{
    self, Camera, ColorMode, Footprint, ForwardOutput, ForwardState, GradRequest, Gradients,
    RasterOptions, Scene, SceneJob,
};
use splat_core::threads::with_threads;
use splat_core::CoreResult;

use crate::errors::InputError;
use crate::ints::{threads_from, u32_from, usize_from};
use crate::run_native;

/// The forward pass's saved state; pass it to `rasterize_backward`. Opaque.
#[pyclass(module = "plantdreamer._core", name = "RasterState", frozen)]
pub struct RasterState {
    pub(crate) inner: ForwardState,
}

#[pymethods]
impl RasterState {
    /// Approximate bytes held (inputs, splats, blend records, tile lists, per-pixel state).
    #[getter]
    fn nbytes(&self) -> usize {
        let s = &self.inner;
        let scene = (s.scene.means.len()
            + s.scene.quats.len()
            + s.scene.scales.len()
            + s.scene.opacities.len()
            + s.scene.colors.len())
            * 4;
        let cams: usize = s
            .per_camera
            .iter()
            .map(|c| {
                c.splats.len() * std::mem::size_of::<raster::project::Splat>()
                    + c.features.len() * 4
                    + (c.bins.tile_offsets.len()
                        + c.bins.isect_gid.len()
                        + c.bins.depth_order.len())
                        * 4
                    + (c.blended.t_final.len() + c.blended.last.len()) * 4
                    + c.records.as_deref().map_or(0, std::mem::size_of_val)
            })
            .sum();
        scene + cams
    }
}

/// A C-contiguous float32 array with the given number of dimensions, borrowed (no copy).
pub(crate) fn f32_view<'py>(
    name: &str,
    obj: &Bound<'py, PyAny>,
    ndim: usize,
) -> PyResult<PyReadonlyArrayDyn<'py, f32>> {
    let arr = obj
        .cast::<PyArrayDyn<f32>>()
        .map_err(|_| InputError::new_err(format!("{name} must be a float32 numpy array")))?;
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

/// The flat data of an array from `f32_view`.
pub(crate) fn flat<'a>(name: &str, view: &'a PyReadonlyArrayDyn<'_, f32>) -> PyResult<&'a [f32]> {
    view.as_slice()
        .map_err(|_| InputError::new_err(format!("{name} must be C-contiguous")))
}

/// A C-contiguous float32 array with the given number of dimensions, as a flat copy (for
/// data the forward state keeps: the caller may change its arrays before the backward).
fn f32_array(name: &str, obj: &Bound<'_, PyAny>, ndim: usize) -> PyResult<(Vec<usize>, Vec<f32>)> {
    let view = f32_view(name, obj, ndim)?;
    Ok((view.shape().to_vec(), flat(name, &view)?.to_vec()))
}

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

/// The arrays and sizes of one forward call, copied out of Python (the forward state keeps
/// them: the caller may change its arrays before the backward).
pub(crate) struct ForwardArgs {
    means: Vec<f32>,
    quats: Vec<f32>,
    scales: Vec<f32>,
    opacities: Vec<f32>,
    colors: Vec<f32>,
    mode: ColorMode,
    viewmats: Vec<f32>,
    ks: Vec<f32>,
    /// Cameras and Gaussians.
    pub(crate) c: usize,
    pub(crate) n: usize,
    width: u32,
    height: u32,
    /// [C, ch] colour behind the features (`forward_with_background`), if any.
    background: Option<Vec<f32>>,
}

impl ForwardArgs {
    /// Checks shapes and copies the arrays (the GIL held).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new(
        means: &Bound<'_, PyAny>,
        quats: &Bound<'_, PyAny>,
        scales: &Bound<'_, PyAny>,
        opacities: &Bound<'_, PyAny>,
        colors: &Bound<'_, PyAny>,
        viewmats: &Bound<'_, PyAny>,
        ks: &Bound<'_, PyAny>,
        width: &Bound<'_, PyAny>,
        height: &Bound<'_, PyAny>,
        sh_degree: Option<&Bound<'_, PyAny>>,
        render_color: bool,
    ) -> PyResult<Self> {
        let width = u32_from(width, "width", 1)?;
        let height = u32_from(height, "height", 1)?;
        let sh_degree = sh_degree
            .filter(|d| !d.is_none())
            .map(|d| usize_from(d, "sh_degree", 0))
            .transpose()?;
        let (ms, m) = f32_array("means", means, 2)?;
        let n = ms[0];
        expect_shape("means", &ms, &[None, Some(3)])?;
        let (qs, q) = f32_array("quats", quats, 2)?;
        expect_shape("quats", &qs, &[Some(n), Some(4)])?;
        let (ss, s) = f32_array("scales", scales, 2)?;
        expect_shape("scales", &ss, &[Some(n), Some(3)])?;
        let (os, o) = f32_array("opacities", opacities, 1)?;
        expect_shape("opacities", &os, &[Some(n)])?;
        let (mode, col) = if !render_color {
            (ColorMode::None, Vec::new())
        } else if let Some(degree) = sh_degree {
            let (cs, c) = f32_array("colors", colors, 3)?;
            expect_shape("colors (SH)", &cs, &[Some(n), None, Some(3)])?;
            (
                ColorMode::Sh {
                    degree,
                    bases: cs[1],
                },
                c,
            )
        } else {
            let (cs, c) = f32_array("colors", colors, 2)?;
            expect_shape("colors", &cs, &[Some(n), None])?;
            (ColorMode::Direct { channels: cs[1] }, c)
        };
        let (vs, v) = f32_array("viewmats", viewmats, 3)?;
        expect_shape("viewmats", &vs, &[None, Some(4), Some(4)])?;
        let c = vs[0];
        let (kshape, k) = f32_array("Ks", ks, 3)?;
        expect_shape("Ks", &kshape, &[Some(c), Some(3), Some(3)])?;
        Ok(Self {
            means: m,
            quats: q,
            scales: s,
            opacities: o,
            colors: col,
            mode,
            viewmats: v,
            ks: k,
            c,
            n,
            width,
            height,
            background: None,
        })
    }

    /// The [C, ch] background to blend behind the colours (None or Python None: none).
    pub(crate) fn with_background(mut self, bg: Option<&Bound<'_, PyAny>>) -> PyResult<Self> {
        let Some(bg) = bg.filter(|b| !b.is_none()) else {
            return Ok(self);
        };
        let (shape, values) = f32_array("background", bg, 2)?;
        let channels = match self.mode {
            ColorMode::Sh { .. } => 3,
            ColorMode::Direct { channels } => channels,
            ColorMode::None => 0,
        };
        expect_shape("background", &shape, &[Some(self.c), Some(channels)])?;
        self.background = Some(values);
        Ok(self)
    }

    /// The scene and cameras (the core's checks: finite matrices, ...); no GIL needed.
    pub(crate) fn job(self) -> CoreResult<SceneJob> {
        let (width, height) = (self.width, self.height);
        let scene = Scene::from_vecs(
            self.means,
            self.quats,
            self.scales,
            self.opacities,
            self.colors,
            self.mode,
        )?;
        let (v, k) = (&self.viewmats, &self.ks);
        let cameras = (0..self.c)
            .map(|i| {
                Camera::from_matrices(&v[16 * i..16 * i + 16], &k[9 * i..9 * i + 9], width, height)
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(SceneJob {
            scene,
            cameras,
            width,
            height,
            background: self.background,
        })
    }
}

/// The options of a forward call: a setting left at None takes `RasterOptions::default()`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn raster_options(
    near_plane: Option<f32>,
    far_plane: Option<f32>,
    eps2d: Option<f32>,
    antialiased: Option<bool>,
    render_depth: Option<bool>,
    tile_size: Option<&Bound<'_, PyAny>>,
    footprint_sigma: Option<f32>,
    tile_ellipse: Option<bool>,
    t_min: Option<f32>,
    simd: Option<bool>,
) -> PyResult<RasterOptions> {
    let def = RasterOptions::default();
    let tile_size = match tile_size.filter(|t| !t.is_none()) {
        Some(t) => u32_from(t, "tile_size", 0)?,
        None => def.tile_size,
    };
    Ok(RasterOptions {
        near_plane: near_plane.unwrap_or(def.near_plane),
        far_plane: far_plane.unwrap_or(def.far_plane),
        eps2d: eps2d.unwrap_or(def.eps2d),
        antialiased: antialiased.unwrap_or(def.antialiased),
        tile_size,
        footprint: footprint_sigma.map_or(def.footprint, Footprint::Sigma),
        tile_ellipse: tile_ellipse.unwrap_or(def.tile_ellipse),
        t_min: t_min.unwrap_or(def.t_min),
        with_depth: render_depth.unwrap_or(def.with_depth),
        simd: simd.unwrap_or(def.simd),
    })
}

/// The Python result of one forward call (see `rasterize_forward`).
pub(crate) fn forward_dict<'py>(
    py: Python<'py>,
    out: ForwardOutput,
    state: ForwardState,
    c: usize,
    n: usize,
) -> PyResult<Bound<'py, PyDict>> {
    let ch = state.channels();
    let (h, w) = (state.height as usize, state.width as usize);
    let d = PyDict::new(py);
    d.set_item(
        "render",
        out.render.into_pyarray(py).reshape([c, h, w, ch])?,
    )?;
    d.set_item("alpha", out.alpha.into_pyarray(py).reshape([c, h, w])?)?;
    d.set_item("radii", out.radii.into_pyarray(py).reshape([c, n, 2])?)?;
    d.set_item("means2d", out.means2d.into_pyarray(py).reshape([c, n, 2])?)?;
    d.set_item("depths", out.depths.into_pyarray(py).reshape([c, n])?)?;
    d.set_item("n_visible", out.n_visible.into_pyarray(py))?;
    d.set_item("n_intersections", out.n_intersections.into_pyarray(py))?;
    let p = PyDict::new(py);
    p.set_item("project", out.profile.project)?;
    p.set_item("sort", out.profile.sort)?;
    p.set_item("bin", out.profile.bin)?;
    p.set_item("blend", out.profile.blend)?;
    d.set_item("profile", p)?;
    d.set_item("state", RasterState { inner: state })?;
    Ok(d)
}

/// Forward rasterization of N Gaussians into C cameras (gsplat 1.5 classic semantics).
///
/// `colors` is [N, D] (used as is) or, with `sh_degree`, [N, K, 3] SH coefficients; it is
/// ignored when `render_color` is false. `background` [C, ch] (colours only) is blended
/// behind the features: render + background (1 - alpha). Returns a dict: render
/// [C, H, W, ch], alpha [C, H, W], radii [C, N, 2] int32, means2d [C, N, 2], depths [C, N],
/// n_visible [C], n_intersections [C], profile (seconds per stage), state. Integer
/// arguments are checked in `ints.rs`.
///
/// A setting left at None takes `RasterOptions::default()`'s value (`raster_defaults`).
#[pyfunction]
#[pyo3(signature = (
    means, quats, scales, opacities, colors, viewmats, ks, width, height, *,
    sh_degree=None, near_plane=None, far_plane=None, eps2d=None, antialiased=None,
    render_color=true, render_depth=None, tile_size=None, footprint_sigma=None,
    tile_ellipse=None, t_min=None, simd=None, threads=None, background=None
))]
// One keyword per setting, as Python callers pass them.
#[allow(clippy::too_many_arguments)]
fn rasterize_forward<'py>(
    py: Python<'py>,
    means: &Bound<'py, PyAny>,
    quats: &Bound<'py, PyAny>,
    scales: &Bound<'py, PyAny>,
    opacities: &Bound<'py, PyAny>,
    colors: &Bound<'py, PyAny>,
    viewmats: &Bound<'py, PyAny>,
    ks: &Bound<'py, PyAny>,
    width: &Bound<'py, PyAny>,
    height: &Bound<'py, PyAny>,
    sh_degree: Option<&Bound<'py, PyAny>>,
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
    background: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let args = ForwardArgs::new(
        means,
        quats,
        scales,
        opacities,
        colors,
        viewmats,
        ks,
        width,
        height,
        sh_degree,
        render_color,
    )?
    .with_background(background)?;
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
    let (c, n) = (args.c, args.n);
    let (out, state) = run_native(py, || {
        let job = args.job()?;
        with_threads(threads, || raster::forward_scene(job, opts))
    })?;
    forward_dict(py, out, state, c, n)
}

/// `RasterOptions::default()` under the keyword names of `rasterize_forward`: the one place
/// the rasterizer's defaults are written (the Python wrapper reads them from here).
/// `footprint_sigma` None is the opacity-aware footprint.
#[pyfunction]
fn raster_defaults(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let def = RasterOptions::default();
    let d = PyDict::new(py);
    d.set_item("near_plane", decimal(def.near_plane))?;
    d.set_item("far_plane", decimal(def.far_plane))?;
    d.set_item("eps2d", decimal(def.eps2d))?;
    d.set_item("antialiased", def.antialiased)?;
    d.set_item("render_depth", def.with_depth)?;
    d.set_item("tile_size", def.tile_size)?;
    let sigma = match def.footprint {
        Footprint::OpacityAware => None,
        Footprint::Sigma(k) => Some(decimal(k)),
    };
    d.set_item("footprint_sigma", sigma)?;
    d.set_item("tile_ellipse", def.tile_ellipse)?;
    d.set_item("t_min", decimal(def.t_min))?;
    d.set_item("simd", def.simd)?;
    Ok(d)
}

/// The shortest decimal that reads back as `v` (0.01, not 0.009999999776482582): Python
/// shows it in signatures, and it converts back to the same f32 bits.
fn decimal(v: f32) -> f64 {
    v.to_string().parse().unwrap_or(v as f64)
}

/// Gradients of the forward call's inputs from dL/d(render) [C, H, W, ch] and
/// dL/d(alpha) [C, H, W] (None: the alpha got no gradient). Groups switched off come back
/// as None; means2d ([C, N, 2], pixels) is always returned.
#[pyfunction]
#[pyo3(signature = (
    state, v_render, v_alpha, *, means=true, quats=true, scales=true, opacities=true,
    colors=true, threads=None
))]
// One keyword per gradient group, as Python callers pass them.
#[allow(clippy::too_many_arguments)]
fn rasterize_backward<'py>(
    py: Python<'py>,
    state: &Bound<'py, RasterState>,
    v_render: &Bound<'py, PyAny>,
    v_alpha: Option<&Bound<'py, PyAny>>,
    means: bool,
    quats: bool,
    scales: bool,
    opacities: bool,
    colors: bool,
    threads: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let threads = threads_from(threads)?;
    let st = &state.get().inner;
    // Read in place: the backward keeps nothing of them.
    let (vr_view, va_view) = upstream_views(st, v_render, v_alpha)?;
    let vr = flat("v_render", &vr_view)?;
    let va = va_view.as_ref().map(|v| flat("v_alpha", v)).transpose()?;
    let want = GradRequest {
        means,
        quats,
        scales,
        opacities,
        colors,
    };
    let grads = run_native(py, || {
        with_threads(threads, || raster::backward(st, vr, va, want))
    })?;
    grads_dict(py, grads, st)
}

/// dL/d(render) [C, H, W, ch] and dL/d(alpha) [C, H, W] (None or Python None: none) of a
/// forward state, borrowed.
#[allow(clippy::type_complexity)]
pub(crate) fn upstream_views<'py>(
    st: &ForwardState,
    v_render: &Bound<'py, PyAny>,
    v_alpha: Option<&Bound<'py, PyAny>>,
) -> PyResult<(
    PyReadonlyArrayDyn<'py, f32>,
    Option<PyReadonlyArrayDyn<'py, f32>>,
)> {
    let c = st.cameras.len();
    let (h, w) = (st.height as usize, st.width as usize);
    let vr_view = f32_view("v_render", v_render, 4)?;
    expect_shape(
        "v_render",
        vr_view.shape(),
        &[Some(c), Some(h), Some(w), Some(st.channels())],
    )?;
    let Some(v_alpha) = v_alpha.filter(|v| !v.is_none()) else {
        return Ok((vr_view, None));
    };
    let va_view = f32_view("v_alpha", v_alpha, 3)?;
    expect_shape("v_alpha", va_view.shape(), &[Some(c), Some(h), Some(w)])?;
    Ok((vr_view, Some(va_view)))
}

/// The Python result of one backward call (see `rasterize_backward`).
pub(crate) fn grads_dict<'py>(
    py: Python<'py>,
    grads: Gradients,
    st: &ForwardState,
) -> PyResult<Bound<'py, PyDict>> {
    let (c, n) = (st.cameras.len(), st.scene.n);
    let d = PyDict::new(py);
    let put = |name: &str, v: Option<Vec<f32>>, shape: Vec<usize>| -> PyResult<()> {
        match v {
            Some(v) => d.set_item(name, v.into_pyarray(py).reshape(shape)?),
            None => d.set_item(name, py.None()),
        }
    };
    put("means", grads.means, vec![n, 3])?;
    put("quats", grads.quats, vec![n, 4])?;
    put("scales", grads.scales, vec![n, 3])?;
    put("opacities", grads.opacities, vec![n])?;
    let color_shape = match st.scene.color_mode {
        ColorMode::Sh { bases, .. } => vec![n, bases, 3],
        ColorMode::Direct { channels } => vec![n, channels],
        ColorMode::None => vec![n, 0],
    };
    put("colors", grads.colors, color_shape)?;
    put("means2d", Some(grads.means2d), vec![c, n, 2])?;
    Ok(d)
}

/// SH colour before the +0.5 offset: coeffs [N, K, 3], dirs [N, 3] (any length) -> [N, 3].
#[pyfunction]
fn eval_sh<'py>(
    py: Python<'py>,
    degree: &Bound<'py, PyAny>,
    coeffs: &Bound<'py, PyAny>,
    dirs: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    let degree = usize_from(degree, "degree", 0)?;
    let (cs, c) = f32_array("coeffs", coeffs, 3)?;
    let n = cs[0];
    expect_shape("coeffs", &cs, &[Some(n), None, Some(3)])?;
    let (ds, d) = f32_array("dirs", dirs, 2)?;
    expect_shape("dirs", &ds, &[Some(n), Some(3)])?;
    if degree > 3 || cs[1] < raster::sh::num_bases(degree) {
        return Err(InputError::new_err(format!(
            "degree {degree} needs 0..=3 and (degree+1)^2 <= K = {}",
            cs[1]
        )));
    }
    let k = cs[1];
    let out: Vec<f32> = (0..n)
        .flat_map(|i| {
            let dir = glam_vec(&d[3 * i..3 * i + 3]);
            raster::sh::eval(degree, &c[i * k * 3..(i + 1) * k * 3], dir)
        })
        .collect();
    out.into_pyarray(py).reshape(vec![n, 3])
}

fn glam_vec(v: &[f32]) -> splat_core::raster::sh::Vec3 {
    splat_core::raster::sh::Vec3::new(v[0], v[1], v[2])
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<RasterState>()?;
    m.add_function(wrap_pyfunction!(rasterize_forward, m)?)?;
    m.add_function(wrap_pyfunction!(rasterize_backward, m)?)?;
    m.add_function(wrap_pyfunction!(raster_defaults, m)?)?;
    m.add_function(wrap_pyfunction!(eval_sh, m)?)?;
    Ok(())
}
