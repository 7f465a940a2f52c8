//! Backward pass of `forward`: image gradients -> gradients of every Gaussian parameter and
//! of the projected 2D means.
//!
//! Per camera: `backward_index` orders the tile intersections by splat, `backward_blend`
//! gives every intersection its gradients in that order, and `backward_chain` sums each
//! splat's intersections and chains them to the 3D parameters.
//!
//! Deterministic for any thread count: tiles write disjoint slices of the per-intersection
//! gradients; each Gaussian then sums its own intersections in tile order and owns its
//! output rows; cameras are accumulated one after another. No floating-point atomics.
//!
//! With a background blended in the forward (`forward_with_background`), each camera's
//! alpha gradient gains the blend's (`background.rs`) before the blend backward.
//!
//! Where a gradient is undefined (culled Gaussians: behind the near plane, NaN/Inf
//! parameters, zero quaternion, opacity < 1/255, off-screen; colour channels clamped at 0;
//! alpha clamped at 0.99 for opacity and geometry) it is zero.

use rayon::prelude::*;

use super::background;
use super::backward_blend::{intersection_gradients, zeroed_gradients};
use super::backward_chain::{Chain, GradRows};
use super::backward_index::SplatIntersections;
use super::batch_lanes::N;
use super::buffers::filled;
use super::forward_pass::ForwardState;
use super::project_backward_batch::CameraLanes;
use super::tile_walk::ISECT_FIXED;
use crate::error::check_len;
use crate::CoreResult;

/// Which parameter groups need gradients (the others are skipped and returned as None).
#[derive(Debug, Clone, Copy, Default)]
pub struct GradRequest {
    pub means: bool,
    pub quats: bool,
    pub scales: bool,
    pub opacities: bool,
    pub colors: bool,
}

/// Gradients, laid out like the inputs. `means2d` is [C, N, 2] in pixels.
#[derive(Debug, Clone, Default)]
pub struct Gradients {
    pub means: Option<Vec<f32>>,
    pub quats: Option<Vec<f32>>,
    pub scales: Option<Vec<f32>>,
    pub opacities: Option<Vec<f32>>,
    pub colors: Option<Vec<f32>>,
    pub means2d: Vec<f32>,
}

/// Gradients of all parameters given dL/d(render) [C, H, W, ch] and dL/d(alpha) [C, H, W]
/// (None: the alpha got no gradient, zero unless a background was blended).
pub fn backward(
    state: &ForwardState,
    v_render: &[f32],
    v_alpha: Option<&[f32]>,
    want: GradRequest,
) -> CoreResult<Gradients> {
    let scene = &state.scene;
    let n = scene.n;
    let c = state.cameras.len();
    let ch = state.channels();
    let pixels = state.width as usize * state.height as usize;
    check_len("v_render", v_render, c * pixels, ch)?;
    if let Some(va) = v_alpha {
        check_len("v_alpha", va, c, pixels)?;
    }

    let cw = scene.color_width();
    let output = |wanted: bool, w: usize| filled(if wanted { n * w } else { 0 }, 0.0f32);
    let mut means = output(want.means, 3)?;
    let mut quats = output(want.quats, 4)?;
    let mut scales = output(want.scales, 3)?;
    let mut opacities = output(want.opacities, 1)?;
    let mut colors = output(want.colors, cw)?;
    let mut means2d = filled(c * n * 2, 0.0f32)?;
    let stride = ISECT_FIXED + ch;

    let no_alpha_gradient = match (v_alpha, &state.background) {
        (None, None) => filled(pixels, 0.0f32)?,
        _ => Vec::new(),
    };
    for (ci, (cam, cs)) in state.cameras.iter().zip(&state.per_camera).enumerate() {
        let v_render_ci = &v_render[ci * pixels * ch..(ci + 1) * pixels * ch];
        let v_alpha_ci = v_alpha.map(|va| &va[ci * pixels..(ci + 1) * pixels]);
        let blended;
        let v_alpha_ci = match (&state.background, v_alpha_ci) {
            (Some(bg), va) => {
                blended = background::alpha_gradient(v_render_ci, va, &bg[ci * ch..(ci + 1) * ch])?;
                &blended[..]
            }
            (None, Some(va)) => va,
            (None, None) => &no_alpha_gradient[..],
        };
        // The index is one sequential pass; the zeroing runs beside it.
        let (index, isect) = rayon::join(
            || SplatIntersections::new(&cs.bins.isect_gid, n),
            || zeroed_gradients(cs.bins.n_intersections() * stride),
        );
        let (index, isect) = (index?, isect?);
        intersection_gradients(
            ch,
            cs,
            &index,
            &isect,
            state.width,
            state.height,
            v_render_ci,
            v_alpha_ci,
            state.opts.simd,
            false,
        );
        let chain = Chain {
            state,
            cs,
            cam: CameraLanes::new(cam),
            centre: cam.centre(),
            isect: &isect,
            index: &index,
            stride,
            ch,
            geometry: want.means || want.quats || want.scales || want.opacities,
        };
        // Blocks of many lane groups: one rayon task per block, not per eight Gaussians.
        const BLOCK: usize = 32 * N;
        let mut rows = Vec::with_capacity(n.div_ceil(BLOCK));
        let mut rest = GradRows {
            means: &mut means,
            quats: &mut quats,
            scales: &mut scales,
            opacities: &mut opacities,
            colors: &mut colors,
            means2d: &mut means2d[ci * n * 2..(ci + 1) * n * 2],
        };
        for first in (0..n).step_by(BLOCK) {
            let m = BLOCK.min(n - first);
            let (head, tail) = split_rows(rest, m);
            rows.push((first, head));
            rest = tail;
        }
        rows.into_par_iter()
            .for_each(|(first, mut out)| chain.block(first, &mut out));
    }

    Ok(Gradients {
        means: want.means.then_some(means),
        quats: want.quats.then_some(quats),
        scales: want.scales.then_some(scales),
        opacities: want.opacities.then_some(opacities),
        colors: (want.colors && cw > 0).then_some(colors),
        means2d,
    })
}

/// The first `m` Gaussians' rows of every output, and the rest.
fn split_rows(rows: GradRows<'_>, m: usize) -> (GradRows<'_>, GradRows<'_>) {
    fn split(v: &mut [f32], m: usize, total: usize) -> (&mut [f32], &mut [f32]) {
        // Row width from the array (0 for an output not requested).
        let w = v.len().checked_div(total).unwrap_or(0);
        v.split_at_mut(m * w)
    }
    let total = rows.means2d.len() / 2;
    let (means, means_t) = split(rows.means, m, total);
    let (quats, quats_t) = split(rows.quats, m, total);
    let (scales, scales_t) = split(rows.scales, m, total);
    let (opacities, opacities_t) = split(rows.opacities, m, total);
    let (colors, colors_t) = split(rows.colors, m, total);
    let (means2d, means2d_t) = rows.means2d.split_at_mut(m * 2);
    (
        GradRows {
            means,
            quats,
            scales,
            opacities,
            colors,
            means2d,
        },
        GradRows {
            means: means_t,
            quats: quats_t,
            scales: scales_t,
            opacities: opacities_t,
            colors: colors_t,
            means2d: means2d_t,
        },
    )
}
