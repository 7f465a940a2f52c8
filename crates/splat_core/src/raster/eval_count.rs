//! How much work the blending kernels do on a forward call: the lane groups they evaluate
//! and the pixel-splat pairs they blend, forward and backward. The roofline benchmark
//! (`examples/raster_timing.rs`, `EVALS=1`) divides these by the timed calls.
//!
//! Replays the blends of a forward state with the kernels' counting instances; the timed
//! passes run the instances without counters, so counting costs nothing when not asked.

use super::backward_blend::{intersection_gradients, zeroed_gradients};
use super::backward_index::SplatIntersections;
use super::forward_blend::blend;
use super::forward_pass::ForwardState;
use super::lanes::LANES;
use super::tile_walk::{EvalCount, ISECT_FIXED};
use crate::CoreResult;

/// Work of the blending kernels, summed over cameras.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Evaluations {
    /// Pixel-splat alphas evaluated by the forward blend (`LANES` per lane group).
    pub forward_evaluated: u64,
    /// Pixel-splat pairs the forward blended (inside, alpha >= 1/255, pixel still live).
    pub forward_blended: u64,
    /// Pixel-splat alphas evaluated by the backward blend.
    pub backward_evaluated: u64,
    /// Pixel-splat pairs the backward differentiated.
    pub backward_blended: u64,
}

/// Counts the blending work of the forward call that produced `state` and of its backward
/// (which visits the same pairs whatever the image gradients are).
pub fn count_evaluations(state: &ForwardState) -> CoreResult<Evaluations> {
    let ch = state.channels();
    let pixels = state.width as usize * state.height as usize;
    let (mut fw, mut bw) = (EvalCount::default(), EvalCount::default());
    for cs in &state.per_camera {
        let mut render = vec![0.0; pixels * ch];
        let mut alpha = vec![0.0; pixels];
        let (_, f) = blend(
            &cs.splats,
            &cs.features,
            cs.records.as_deref(),
            ch,
            &cs.bins,
            state.width,
            state.height,
            state.opts.t_min,
            state.opts.simd,
            true,
            &mut render,
            &mut alpha,
        )?;
        fw.add(f);
        let (v_render, v_alpha) = (vec![0.0; pixels * ch], vec![0.0; pixels]);
        let rows = SplatIntersections::new(&cs.bins.isect_gid, state.scene.n)?;
        let grads = zeroed_gradients(cs.bins.n_intersections() * (ISECT_FIXED + ch))?;
        let b = intersection_gradients(
            ch,
            cs,
            &rows,
            &grads,
            state.width,
            state.height,
            &v_render,
            &v_alpha,
            state.opts.simd,
            true,
        );
        bw.add(b);
    }
    Ok(Evaluations {
        forward_evaluated: fw.groups * LANES as u64,
        forward_blended: fw.blended,
        backward_evaluated: bw.groups * LANES as u64,
        backward_blended: bw.blended,
    })
}
