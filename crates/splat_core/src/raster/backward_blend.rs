//! Backward of the blending stage: per-tile, per-intersection gradients, walking every
//! pixel back to front from its final transmittance.
//!
//! Per pixel, for splat k (front to back index) with alpha_k, transmittance T_k before it
//! and `buf` = the features blended behind it:
//!   dC/df_k = alpha_k T_k,   dC/dalpha_k = f_k T_k - buf / (1 - alpha_k),
//!   d(1 - T_final)/dalpha_k = T_final / (1 - alpha_k).
//! T_k is recovered as T_{k+1} / (1 - alpha_k); alpha <= 0.99 keeps that division tame and
//! 1 - alpha is floored at 1e-6 anyway. Where alpha was clamped at 0.99 it does not depend on
//! opacity or position, so those gradients are zero there (gsplat's gating).
//!
//! Like the forward, a splat's footprint is walked in groups of `LANES` pixels; a splat's
//! gradient sums are kept per lane and added up in a fixed tree at the end, identically in
//! the AVX2 kernel (`blend_avx2`) and the scalar one here, so both give the same bits.
//!
//! Each tile writes only its own intersections' rows of the intersection-gradient array,
//! so tiles run in parallel without locks; the caller sums a splat's intersections in tile
//! order.

use std::sync::atomic::AtomicU32;

use rayon::prelude::*;

use crate::memory::try_vec;
use crate::CoreResult;

use super::backward_index::SplatIntersections;
use super::forward_pass::CameraState;
use super::lanes::{exp_neg, lane_sum, sigma_at, LANES};
use super::options::{ALPHA_MAX, ALPHA_MIN};
use super::tile_geometry::{pixel_boxes, TileList, TileRect};
use super::tile_walk::{
    for_each_splat_back, kept_scratch, BackOut, BackScratch, BackTile, EvalCount, ISECT_FIXED,
};

/// Per-intersection gradients of one camera, `ISECT_FIXED + ch` values per intersection,
/// stored (as f32 bits) in `grads` at the intersection's splat-major row
/// (`SplatIntersections`); `grads` comes zeroed (`zeroed_gradients`). With `count`, runs
/// the kernels' counting instances and returns their work (zero otherwise).
///
/// The kernels put every splat's row straight at its splat-major place (`BackOut::Shared`).
#[allow(clippy::too_many_arguments)]
pub fn intersection_gradients(
    ch: usize,
    cs: &CameraState,
    rows: &SplatIntersections,
    grads: &[AtomicU32],
    width: u32,
    height: u32,
    v_render: &[f32],
    v_alpha: &[f32],
    simd: bool,
    count: bool,
) -> EvalCount {
    let (bins, blended) = (&cs.bins, &cs.blended);
    let ts = bins.tile_size as usize;
    let tp = ts * ts;
    let totals = std::sync::Mutex::new(EvalCount::default());
    (0..bins.n_tiles())
        .into_par_iter()
        .with_max_len(4)
        .for_each(|t| {
            SCRATCH.with_borrow_mut(|kept| {
                let (scratch, list) =
                    kept_scratch(kept, |sc| sc.fits(ts, ch), || BackScratch::new(ts, ch));
                let range = bins.tile_range(t);
                if range.is_empty() {
                    return;
                }
                let rect = TileRect::new(t, bins, width, height);
                scratch.reset(
                    &rect,
                    ch,
                    width as usize,
                    &blended.t_final[t * tp..(t + 1) * tp],
                    &blended.last[t * tp..(t + 1) * tp],
                    v_render,
                    v_alpha,
                );
                // Splats behind every pixel's last contributor never reach the kernel: only
                // the list's front part is gathered.
                let used = scratch.last.iter().copied().max().unwrap_or(0) as usize;
                let range = range.start..range.start + used.min(range.len());
                let gids = &bins.isect_gid[range.clone()];
                match &cs.records {
                    Some(records) => list.gather_records(gids, records, ch),
                    None => list.gather(gids, &cs.splats, &cs.features, ch),
                }
                pixel_boxes(&list.splats, &rect, &mut list.boxes);
                let tile = BackTile {
                    splats: &list.splats,
                    boxes: &list.boxes,
                    features: &list.features,
                    rect,
                    simd,
                };
                let mut out = BackOut::Shared {
                    grads,
                    rows: rows.row_of(range),
                };
                backward_tile(&tile, ch, scratch, &mut out, count);
                if count {
                    let mut t = totals.lock().unwrap_or_else(|e| e.into_inner());
                    t.add(std::mem::take(&mut scratch.evals));
                }
            })
        });
    totals.into_inner().unwrap_or_else(|e| e.into_inner())
}

thread_local! {
    /// Each thread's tile scratch, kept between tiles and calls.
    static SCRATCH: std::cell::RefCell<Option<(BackScratch, TileList)>> =
        const { std::cell::RefCell::new(None) };
}

/// A zeroed intersection-gradient array for `intersection_gradients` (`len` values),
/// filled in parallel.
pub fn zeroed_gradients(len: usize) -> CoreResult<Vec<AtomicU32>> {
    let mut out = try_vec(len)?;
    (0..len)
        .into_par_iter()
        .map(|_| AtomicU32::new(0))
        .collect_into_vec(&mut out);
    Ok(out)
}

/// One tile's intersection gradients into `out` (rows +0 on entry: the AVX2 kernel puts no
/// row for a splat no pixel differentiated).
fn backward_tile(
    tile: &BackTile,
    ch: usize,
    scratch: &mut BackScratch,
    out: &mut BackOut,
    count: bool,
) {
    #[cfg(target_arch = "x86_64")]
    if tile.simd
        && ch <= super::blend_avx2::MAX_BACKWARD_CHANNELS
        && std::arch::is_x86_feature_detected!("avx2")
    {
        use super::blend_avx2::backward_tile;
        match count {
            false => backward_tile::<false>(tile, ch, scratch, out),
            true => backward_tile::<true>(tile, ch, scratch, out),
        }
        return;
    }
    match count {
        false => backward_tile_scalar::<false>(tile, ch, scratch, out),
        true => backward_tile_scalar::<true>(tile, ch, scratch, out),
    }
}

/// The lane rules written out per pixel; the AVX2 kernel performs the same operations and
/// skips the same lane groups, so both count the same work.
pub(super) fn backward_tile_scalar<const COUNT: bool>(
    tile: &BackTile,
    ch: usize,
    scratch: &mut BackScratch,
    out: &mut BackOut,
) {
    let (plane, stride) = (scratch.geo.plane(), scratch.geo.stride);
    let mut acc_f = vec![[0.0f32; LANES]; ch];
    for_each_splat_back(tile, ch, scratch, out, |sp, sc, o| {
        let [ca, cb, cc] = sp.s.conic;
        // Lane sums of v_x, v_y, v_a, v_b, v_c, v_opacity.
        let mut acc = [[0.0f32; LANES]; ISECT_FIXED];
        acc_f.iter_mut().for_each(|a| *a = [0.0; LANES]);
        for gi in sp.fp.groups.clone() {
            for ly in sc.geo.group_rows[gi].clone() {
                let base = ly * stride + sp.fp.col0 + gi * LANES;
                let active = |i: usize| {
                    let x = sc.geo.xs[sp.fp.col0 + gi * LANES + i];
                    (x > sp.fp.xlo) & (x < sp.fp.xhi) & (sp.k < sc.last[base + i])
                };
                if COUNT && (0..LANES).any(active) {
                    sc.evals.groups += 1;
                }
                for i in 0..LANES {
                    let l = base + i;
                    let x = sc.geo.xs[sp.fp.col0 + gi * LANES + i];
                    let active = active(i);
                    let dx = sp.s.xy[0] - x;
                    let dy = sc.geo.row_dy[ly];
                    let sigma = sigma_at(ca, dx, sc.geo.row_c[ly], sc.geo.row_b[ly]);
                    let vis = exp_neg(-sigma);
                    let raw = sp.s.opacity * vis;
                    let alpha = raw.min(ALPHA_MAX);
                    if !(active & (sigma >= 0.0) & (alpha >= ALPHA_MIN)) {
                        continue;
                    }
                    if COUNT {
                        sc.evals.blended += 1;
                    }
                    let ra = 1.0 / (1.0 - alpha).max(1e-6);
                    let t_k = sc.trans[l] * ra;
                    let fac = alpha * t_k;
                    let mut v_al = sc.va_tf[l] * ra;
                    for (c, (a, &fc)) in acc_f.iter_mut().zip(sp.f).enumerate() {
                        let vo = sc.v_out[c * plane + l];
                        let b = &mut sc.buf[c * plane + l];
                        a[i] += fac * vo;
                        v_al += (fc * t_k - *b * ra) * vo;
                        *b += fc * fac;
                    }
                    sc.trans[l] = t_k;
                    if raw <= ALPHA_MAX {
                        let v_sigma = -raw * v_al;
                        acc[0][i] += v_sigma * (ca * dx + cb * dy);
                        acc[1][i] += v_sigma * (cb * dx + cc * dy);
                        acc[2][i] += 0.5 * v_sigma * dx * dx;
                        acc[3][i] += v_sigma * dx * dy;
                        acc[4][i] += 0.5 * v_sigma * dy * dy;
                        acc[5][i] += vis * v_al;
                    }
                }
            }
        }
        for (o, a) in o.iter_mut().zip(acc.iter().chain(&acc_f)) {
            *o = lane_sum(a);
        }
        true
    });
}
