//! Backward pass of `forward`: image gradients -> gradients of every Gaussian parameter and
//! of the projected 2D means.
//!
//! Deterministic for any thread count: tiles write disjoint slices of the per-intersection
//! gradients; each Gaussian then sums its own intersections in tile order and owns its
//! output row; cameras are accumulated one after another. No floating-point atomics.
//!
//! Where a gradient is undefined (culled Gaussians: behind the near plane, NaN/Inf
//! parameters, zero quaternion, opacity < 1/255, off-screen; colour channels clamped at 0;
//! alpha clamped at 0.99 for opacity and geometry) it is zero.

use rayon::prelude::*;

use super::backward_blend::intersection_gradients;
use super::forward_pass::ForwardState;
use super::project::{project_backward, SplatGrad};
use super::scene::ColorMode;
use super::sh;
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

// Row layout of the per-Gaussian accumulator.
const MEAN: usize = 0;
const QUAT: usize = 3;
const SCALE: usize = 7;
const OPAC: usize = 10;
const COLOR: usize = 11;

/// Each splat's intersection gradients summed in tile order: sequential passes over the
/// tile-major gradients (a splat's tiles come in increasing tile order), so the order, and
/// the bits, do not depend on the thread count. One pass per thread, each summing the
/// splats of its own index range: every pass reads all the splat indices but only its
/// share of the gradient rows.
fn sum_per_splat(isect: &[f32], gids: &[u32], n: usize, stride: usize) -> Vec<f32> {
    let mut sums = vec![0.0f32; n * stride];
    let per_pass = n.div_ceil(rayon::current_num_threads()).max(1);
    sums.par_chunks_mut(per_pass * stride)
        .enumerate()
        .for_each(|(p, own)| {
            let lo = p * per_pass;
            let len = own.len() / stride;
            for (row, &g) in isect.chunks_exact(stride).zip(gids) {
                // One unsigned comparison: below `lo` wraps around to a large value.
                let i = (g as usize).wrapping_sub(lo);
                if i < len {
                    for (s, v) in own[i * stride..(i + 1) * stride].iter_mut().zip(row) {
                        *s += v;
                    }
                }
            }
        });
    sums
}

/// Gradients of all parameters given dL/d(render) [C, H, W, ch] and dL/d(alpha) [C, H, W].
pub fn backward(
    state: &ForwardState,
    v_render: &[f32],
    v_alpha: &[f32],
    want: GradRequest,
) -> CoreResult<Gradients> {
    let scene = &state.scene;
    let n = scene.n;
    let c = state.cameras.len();
    let ch = state.channels();
    let cc = scene.color_channels();
    let pixels = state.width as usize * state.height as usize;
    check_len("v_render", v_render, c * pixels, ch)?;
    check_len("v_alpha", v_alpha, c, pixels)?;

    let cw = scene.color_width();
    let gw = COLOR + cw;
    let geometry = want.means || want.quats || want.scales || want.opacities;
    let mut acc = vec![0.0f32; n * gw];
    let mut means2d = vec![0.0f32; c * n * 2];
    let stride = ISECT_FIXED + ch;

    for (ci, (cam, cs)) in state.cameras.iter().zip(&state.per_camera).enumerate() {
        let (isect, _) = intersection_gradients(
            ch,
            cs,
            state.width,
            state.height,
            &v_render[ci * pixels * ch..(ci + 1) * pixels * ch],
            &v_alpha[ci * pixels..(ci + 1) * pixels],
            state.opts.simd,
            false,
        );
        let centre = cam.centre();
        let bins = &cs.bins;
        let sums = sum_per_splat(&isect, &bins.isect_gid, n, stride);
        drop(isect);
        acc.par_chunks_mut(gw)
            .zip(means2d[ci * n * 2..(ci + 1) * n * 2].par_chunks_mut(2))
            .zip(sums.par_chunks(stride))
            .enumerate()
            .for_each(|(i, ((row, m2d), sum))| {
                // A Gaussian no pixel differentiated (hidden behind others, or its pixels
                // have zero gradients) would add only zeros: its chain is skipped. The
                // bits are the same, as `row` is never -0 (it starts at +0, and a sum is
                // -0 only if both terms are), so adding +0 or -0 keeps it.
                if !cs.splats[i].visible() || sum.iter().all(|&v| v == 0.0) {
                    return;
                }
                m2d.copy_from_slice(&sum[..2]);
                let v_feat = &sum[ISECT_FIXED..];
                let g = scene.gaussian(i);
                if geometry {
                    let sg = SplatGrad {
                        xy: [sum[0], sum[1]],
                        conic: [sum[2], sum[3], sum[4]],
                        opacity: sum[5],
                        depth: if state.opts.with_depth {
                            v_feat[cc]
                        } else {
                            0.0
                        },
                    };
                    let g3 = project_backward(&g, cam, &state.opts, &sg);
                    for d in 0..3 {
                        row[MEAN + d] += g3.mean[d];
                        row[SCALE + d] += g3.scale[d];
                    }
                    for d in 0..4 {
                        row[QUAT + d] += g3.quat[d];
                    }
                    row[OPAC] += g3.opacity;
                }
                match scene.color_mode {
                    ColorMode::None => {}
                    ColorMode::Direct { .. } => {
                        if want.colors {
                            for (o, v) in row[COLOR..].iter_mut().zip(&v_feat[..cc]) {
                                *o += v;
                            }
                        }
                    }
                    ColorMode::Sh { degree, .. } => {
                        let coeffs = scene.color_row(i);
                        let dir = g.mean - centre;
                        let raw = sh::eval(degree, coeffs, dir);
                        // max(x + 0.5, 0) passes the gradient where x + 0.5 >= 0.
                        let v_rgb =
                            [0, 1, 2].map(|c| if raw[c] + 0.5 >= 0.0 { v_feat[c] } else { 0.0 });
                        let v_coeffs = if want.colors {
                            Some(&mut row[COLOR..])
                        } else {
                            None
                        };
                        let v_dir = sh::eval_backward(degree, coeffs, dir, v_rgb, v_coeffs);
                        for d in 0..3 {
                            row[MEAN + d] += v_dir[d];
                        }
                    }
                }
            });
    }

    // Presized and parallel: collecting a flat_map grows the vector step by step.
    let column = |lo: usize, w: usize| -> Vec<f32> {
        let mut out = vec![0.0f32; n * w];
        out.par_chunks_mut(w)
            .zip(acc.par_chunks(gw))
            .for_each(|(o, r)| o.copy_from_slice(&r[lo..lo + w]));
        out
    };
    Ok(Gradients {
        means: want.means.then(|| column(MEAN, 3)),
        quats: want.quats.then(|| column(QUAT, 4)),
        scales: want.scales.then(|| column(SCALE, 3)),
        opacities: want.opacities.then(|| column(OPAC, 1)),
        colors: (want.colors && cw > 0).then(|| column(COLOR, cw)),
        means2d,
    })
}
