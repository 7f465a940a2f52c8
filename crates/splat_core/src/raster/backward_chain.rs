//! The last stage of the backward: from each splat's summed intersection gradients (2D
//! position, conic, opacity, features) to the gradients of its 3D parameters, for one
//! camera, straight into the output arrays.
//!
//! Gaussians run in blocks (one rayon task each) and, inside a block, eight at a time
//! through the projection's backward (`project_backward_batch`, the same bits as the
//! per-Gaussian `project_backward`); colours and SH follow per Gaussian. A splat's sum
//! adds its intersections in tile order, whatever the thread count. A Gaussian whose sum
//! is all zeros (hidden behind others, or its pixels have zero gradients) would add only
//! zeros: it is skipped. The bits are the same, as an output is never -0 (it starts at +0,
//! and a sum is -0 only if both terms are), so adding +0 or -0 keeps it.

use std::sync::atomic::{AtomicU32, Ordering};

use glam::Vec3;

use super::backward_index::SplatIntersections;
use super::batch_lanes::N;
use super::forward_pass::{CameraState, ForwardState};
use super::project_backward_batch::{
    project_backward_lanes, CameraLanes, GaussianLanes, SplatGradLanes,
};
use super::scene::ColorMode;
use super::sh;
use super::tile_walk::ISECT_FIXED;

/// One block's rows of every output, empty where that gradient is not requested.
pub(super) struct GradRows<'a> {
    pub means: &'a mut [f32],
    pub quats: &'a mut [f32],
    pub scales: &'a mut [f32],
    pub opacities: &'a mut [f32],
    pub colors: &'a mut [f32],
    /// dL/d(means2d) of this camera, [Gaussian][2].
    pub means2d: &'a mut [f32],
}

/// What the chain of one camera reads.
pub(super) struct Chain<'a> {
    pub state: &'a ForwardState,
    pub cs: &'a CameraState,
    pub cam: CameraLanes,
    /// The camera centre (SH view directions).
    pub centre: Vec3,
    /// Per-intersection gradients (f32 bits), splat-major, `stride` values each.
    pub isect: &'a [AtomicU32],
    pub index: &'a SplatIntersections,
    pub stride: usize,
    /// Feature channels per splat (`cs.features` rows).
    pub ch: usize,
    /// Whether any of means, quats, scales, opacities is requested.
    pub geometry: bool,
}

impl Chain<'_> {
    /// Gaussians first .. first + `out.means2d.len() / 2`.
    pub fn block(&self, first: usize, out: &mut GradRows) {
        // One instance per common row width (colour, colour + depth, depth only): with
        // the width known, the sums unroll and index without divisions.
        match self.stride {
            9 => self.block_rows::<9>(first, out),
            10 => self.block_rows::<10>(first, out),
            7 => self.block_rows::<7>(first, out),
            _ => self.block_rows::<0>(first, out),
        }
    }

    /// `block` with rows of `S` values (0: `self.stride`, known only at run time).
    /// Gaussians with a nonzero sum are chained eight at a time, in index order.
    #[inline(always)]
    fn block_rows<const S: usize>(&self, first: usize, out: &mut GradRows) {
        let m = out.means2d.len() / 2;
        let stride = if S == 0 { self.stride } else { S };
        let mut sums = vec![0.0f32; N * stride];
        // Rows in `out` of the Gaussians whose sums are in `sums`.
        let (mut batch, mut filled) = ([0usize; N], 0);
        for r in 0..m {
            // Culled splats have no intersections.
            let i = first + r;
            let rows = self.index.rows(i, i + 1);
            if rows.is_empty() {
                continue;
            }
            let sum = &mut sums[filled * stride..(filled + 1) * stride];
            sum.fill(0.0);
            for row in self.isect[rows.start * stride..rows.end * stride].chunks_exact(stride) {
                for (s, v) in sum.iter_mut().zip(row) {
                    *s += f32::from_bits(v.load(Ordering::Relaxed));
                }
            }
            if sum.iter().any(|&v| v != 0.0) {
                batch[filled] = r;
                filled += 1;
                if filled == N {
                    self.lanes(first, &batch[..N], &sums, out);
                    filled = 0;
                }
            }
        }
        if filled > 0 {
            self.lanes(first, &batch[..filled], &sums, out);
        }
    }

    /// Up to eight Gaussians, `first + batch[l]` (row `batch[l]` in `out`, sums in row l
    /// of `sums`).
    fn lanes(&self, first: usize, batch: &[usize], sums: &[f32], out: &mut GradRows) {
        let (state, scene) = (self.state, &self.state.scene);
        let stride = self.stride;
        let grads = self.geometry.then(|| {
            // Lanes past the last Gaussian repeat it; their results are dropped.
            let lane: [usize; N] = std::array::from_fn(|l| l.min(batch.len() - 1));
            let g = GaussianLanes::load(scene, &lane.map(|l| first + batch[l]));
            let depth = state
                .opts
                .with_depth
                .then(|| ISECT_FIXED + scene.color_channels());
            let v = SplatGradLanes::load(sums, stride, &lane, depth);
            project_backward_lanes(&g, &self.cam, &state.opts, &v)
        });
        for (l, &r) in batch.iter().enumerate() {
            let (i, sum) = (first + r, &sums[l * stride..(l + 1) * stride]);
            out.means2d[r * 2..r * 2 + 2].copy_from_slice(&sum[..2]);
            if let Some(grads) = &grads {
                let g3 = &grads[l];
                add(out.means, r, &g3.mean.to_array());
                add(out.quats, r, &g3.quat);
                add(out.scales, r, &g3.scale.to_array());
                add(out.opacities, r, &[g3.opacity]);
            }
            self.colors(i, r, out, &sum[ISECT_FIXED..]);
        }
    }

    /// The colour chain of Gaussian `i` (row `r`): direct colours, or SH coefficients and
    /// the view direction's share of the mean's gradient.
    fn colors(&self, i: usize, r: usize, out: &mut GradRows, v_feat: &[f32]) {
        let scene = &self.state.scene;
        let cc = scene.color_channels();
        let cw = scene.color_width();
        let colors = out.colors.get_mut(r * cw..(r + 1) * cw);
        match scene.color_mode {
            ColorMode::None => {}
            ColorMode::Direct { .. } => {
                if let Some(row) = colors {
                    for (o, v) in row.iter_mut().zip(&v_feat[..cc]) {
                        *o += v;
                    }
                }
            }
            ColorMode::Sh { degree, .. } => {
                let coeffs = scene.color_row(i);
                let dir = scene.gaussian(i).mean - self.centre;
                // max(x + 0.5, 0) passes the gradient where x + 0.5 >= 0: wherever the
                // forward's colour is > 0, and else where x + 0.5 is exactly 0, which only
                // the SH value itself tells (computed as the forward did, so rarely).
                let feat = &self.cs.features[i * self.ch..i * self.ch + 3];
                let raw = feat
                    .iter()
                    .any(|&f| f <= 0.0)
                    .then(|| sh::eval(degree, coeffs, dir));
                let passes = |c: usize| match raw {
                    Some(raw) => raw[c] + 0.5 >= 0.0,
                    None => true,
                };
                let v_rgb = [0, 1, 2].map(|c| if passes(c) { v_feat[c] } else { 0.0 });
                let v_dir = sh::eval_backward(degree, coeffs, dir, v_rgb, colors);
                add(out.means, r, &v_dir.to_array());
            }
        }
    }
}

/// Adds `v` to row `r` of `out` (rows of `v.len()`); nothing if `out` is empty (not
/// requested).
#[inline(always)]
fn add(out: &mut [f32], r: usize, v: &[f32]) {
    if let Some(row) = out.get_mut(r * v.len()..(r + 1) * v.len()) {
        for (o, x) in row.iter_mut().zip(v) {
            *o += x;
        }
    }
}
