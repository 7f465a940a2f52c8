//! A rasterizer call's arguments from Python: each scene's arrays and sizes (copied: the
//! forward state keeps them), the settings the scenes share, their defaults, and a
//! backward's upstream gradients (borrowed).

use numpy::{PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use splat_core::raster::{
    Camera, ColorMode, Footprint, ForwardState, RasterOptions, Scene, SceneJob,
};
use splat_core::CoreResult;

use crate::arrays::{expect_shape, f32_array, f32_view};
use crate::errors::InputError;
use crate::ints::{u32_from, usize_from};

/// One scene's arrays and sizes, copied out of Python (the forward state keeps them: the
/// caller may change its arrays before the backward).
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
    /// One scene from its dict: means [N, 3], quats [N, 4], scales [N, 3], opacities [N],
    /// colors ([N, D], or [N, K, 3] SH coefficients with sh_degree; not read when
    /// `render_color` is false), viewmats [C, 4, 4], Ks [C, 3, 3], width, height, and
    /// optionally sh_degree and background [C, ch]. Checks shapes and copies the arrays
    /// (the GIL held).
    pub(crate) fn from_scene(scene: &Bound<'_, PyAny>, render_color: bool) -> PyResult<Self> {
        let d = scene.cast::<PyDict>().map_err(|_| {
            InputError::new_err("each scene must be a dict of its arrays and image size")
        })?;
        let get = |key: &str| -> PyResult<Bound<'_, PyAny>> {
            d.get_item(key)?
                .ok_or_else(|| InputError::new_err(format!("the scene has no {key:?}")))
        };
        let (means, quats, scales) = (get("means")?, get("quats")?, get("scales")?);
        let (opacities, colors) = (get("opacities")?, get("colors")?);
        let (viewmats, ks) = (get("viewmats")?, get("Ks")?);
        let (width, height) = (get("width")?, get("height")?);
        let width = u32_from(&width, "width", 1)?;
        let height = u32_from(&height, "height", 1)?;
        let sh_degree = d
            .get_item("sh_degree")?
            .filter(|d| !d.is_none())
            .map(|d| usize_from(&d, "sh_degree", 0))
            .transpose()?;
        let (ms, m) = f32_array("means", &means, 2)?;
        let n = ms[0];
        expect_shape("means", &ms, &[None, Some(3)])?;
        let (qs, q) = f32_array("quats", &quats, 2)?;
        expect_shape("quats", &qs, &[Some(n), Some(4)])?;
        let (ss, s) = f32_array("scales", &scales, 2)?;
        expect_shape("scales", &ss, &[Some(n), Some(3)])?;
        let (os, o) = f32_array("opacities", &opacities, 1)?;
        expect_shape("opacities", &os, &[Some(n)])?;
        let (mode, col) = if !render_color {
            (ColorMode::None, Vec::new())
        } else if let Some(degree) = sh_degree {
            let (cs, c) = f32_array("colors", &colors, 3)?;
            expect_shape("colors (SH)", &cs, &[Some(n), None, Some(3)])?;
            (
                ColorMode::Sh {
                    degree,
                    bases: cs[1],
                },
                c,
            )
        } else {
            let (cs, c) = f32_array("colors", &colors, 2)?;
            expect_shape("colors", &cs, &[Some(n), None])?;
            (ColorMode::Direct { channels: cs[1] }, c)
        };
        let (vs, v) = f32_array("viewmats", &viewmats, 3)?;
        expect_shape("viewmats", &vs, &[None, Some(4), Some(4)])?;
        let c = vs[0];
        let (kshape, k) = f32_array("Ks", &ks, 3)?;
        expect_shape("Ks", &kshape, &[Some(c), Some(3), Some(3)])?;
        let args = Self {
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
        };
        args.with_background(d.get_item("background")?.as_ref())
    }

    /// The [C, ch] background to blend behind the colours (None or Python None: none).
    fn with_background(mut self, bg: Option<&Bound<'_, PyAny>>) -> PyResult<Self> {
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

/// `RasterOptions::default()` under the keyword names of `rasterize_forward_many`: the one
/// place the rasterizer's defaults are written (the Python wrapper reads them from here).
/// `footprint_sigma` None is the opacity-aware footprint.
#[pyfunction]
pub(crate) fn raster_defaults(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
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

/// dL/d(render) [C, H, W, ch] and dL/d(alpha) [C, H, W] (None or Python None: none) of a
/// forward state, borrowed: the backward keeps nothing of them.
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
