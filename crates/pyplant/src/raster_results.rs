//! A rasterizer call's results for Python: the forward's arrays and its opaque saved
//! state, and the backward's gradients.

use numpy::{IntoPyArray, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use splat_core::raster::{self, ColorMode, ForwardOutput, ForwardState, Gradients};

/// The forward pass's saved state; pass it to `rasterize_backward_many`. Opaque.
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

/// One scene's forward result: render [C, H, W, ch], alpha [C, H, W], radii [C, N, 2]
/// int32, means2d [C, N, 2], depths [C, N], n_visible [C], n_intersections [C], profile
/// (seconds per stage) and state.
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

/// One scene's gradients: means, quats, scales, opacities and colors in the inputs'
/// shapes (None for a group switched off), and means2d [C, N, 2] (pixels), always.
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
