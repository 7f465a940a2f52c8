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
//! Each tile writes only its own slice of the intersection-gradient array, so tiles run in
//! parallel without locks or atomics; the caller sums a splat's intersections in tile
//! order.

use rayon::prelude::*;

use super::forward::{
    exp_neg, sigma_at, BlendSplat, LaneFootprint, TileGeometry, TileList, TileRect, LANES,
};
use super::CameraState;
use super::{ALPHA_MAX, ALPHA_MIN};

/// Gradient values stored per intersection: xy (2), conic (3), opacity (1), features (ch).
pub const ISECT_FIXED: usize = 6;

/// Per-intersection gradients of one camera, tile-major like `TileBins::isect_gid`.
pub fn blend_backward(
    ch: usize,
    cs: &CameraState,
    width: u32,
    height: u32,
    v_render: &[f32],
    v_alpha: &[f32],
    simd: bool,
) -> Vec<f32> {
    let (bins, blended) = (&cs.bins, &cs.blended);
    let stride = ISECT_FIXED + ch;
    let ts = bins.tile_size as usize;
    let tp = ts * ts;
    let mut grads = vec![0.0f32; bins.n_intersections() * stride];
    // Split the gradient array into the tiles' own slices.
    let mut slices: Vec<&mut [f32]> = Vec::with_capacity(bins.n_tiles());
    let mut rest = grads.as_mut_slice();
    for t in 0..bins.n_tiles() {
        let (head, tail) = rest.split_at_mut(bins.tile_range(t).len() * stride);
        slices.push(head);
        rest = tail;
    }
    slices
        .into_par_iter()
        .enumerate()
        .with_max_len(4)
        .for_each_init(
            || (BackScratch::new(ts, ch), TileList::default()),
            |(scratch, list), (t, out)| {
                if out.is_empty() {
                    return;
                }
                let rect = TileRect::new(t, bins, width, height);
                list.gather(
                    &bins.isect_gid[bins.tile_range(t)],
                    &cs.splats,
                    &cs.features,
                    ch,
                );
                let tile = BackTile {
                    splats: &list.splats,
                    features: &list.features,
                    rect,
                    simd,
                };
                scratch.reset(
                    &rect,
                    ch,
                    width as usize,
                    &blended.t_final[t * tp..(t + 1) * tp],
                    &blended.last[t * tp..(t + 1) * tp],
                    v_render,
                    v_alpha,
                );
                backward_tile(&tile, ch, scratch, out);
            },
        );
    grads
}

/// What one tile's backward reads: its list (front to back) and its pixels.
pub(super) struct BackTile<'a> {
    pub splats: &'a [BlendSplat],
    pub features: &'a [f32],
    pub rect: TileRect,
    /// Use the SIMD kernel when the CPU has one.
    pub simd: bool,
}

/// Per-tile pixel state of the backward, structure of arrays with rows padded to whole
/// lane groups (padding pixels have `last` 0, so no splat touches them).
pub(super) struct BackScratch {
    pub geo: TileGeometry,
    /// Transmittance after the splat being processed (starts at the final T).
    pub trans: Vec<f32>,
    pub last: Vec<u32>,
    /// dL/d(alpha image) times the final T.
    pub va_tf: Vec<f32>,
    /// Planar dL/d(render) and features blended behind the current splat.
    pub v_out: Vec<f32>,
    pub buf: Vec<f32>,
}

impl BackScratch {
    pub(super) fn new(ts: usize, ch: usize) -> Self {
        let geo = TileGeometry::new(ts);
        let plane = geo.plane();
        Self {
            geo,
            trans: vec![0.0; plane],
            last: vec![0; plane],
            va_tf: vec![0.0; plane],
            v_out: vec![0.0; plane * ch],
            buf: vec![0.0; plane * ch],
        }
    }

    /// Loads the tile's pixels (tile-major `t_final` / `last`, row-major gradients).
    pub(super) fn reset(
        &mut self,
        rect: &TileRect,
        ch: usize,
        width: usize,
        t_final: &[f32],
        last: &[u32],
        v_render: &[f32],
        v_alpha: &[f32],
    ) {
        let (tw, th) = ((rect.x1 - rect.x0) as usize, (rect.y1 - rect.y0) as usize);
        let (plane, ts, stride) = (self.geo.plane(), self.geo.ts, self.geo.stride);
        self.last.fill(0);
        self.buf.fill(0.0);
        for ly in 0..th {
            let (src, dst) = (ly * ts, ly * stride);
            let pix = (rect.y0 as usize + ly) * width + rect.x0 as usize;
            self.trans[dst..dst + tw].copy_from_slice(&t_final[src..src + tw]);
            self.last[dst..dst + tw].copy_from_slice(&last[src..src + tw]);
            for lx in 0..tw {
                self.va_tf[dst + lx] = v_alpha[pix + lx] * t_final[src + lx];
                for c in 0..ch {
                    self.v_out[c * plane + dst + lx] = v_render[(pix + lx) * ch + c];
                }
            }
        }
        self.geo.set_tile(rect);
    }
}

/// One splat of a tile's list as the backward kernels see it.
pub(super) struct BackSplat<'a> {
    pub s: &'a BlendSplat,
    pub f: &'a [f32],
    /// Its position in the tile list: pixels with `last > k` saw it.
    pub k: u32,
    pub fp: LaneFootprint,
}

/// Walks the tile's list back to front from the last splat any pixel used, and calls
/// `kernel(splat, scratch, out)` with the splat's slice of the gradient array.
#[inline(always)]
pub(super) fn for_each_splat_back(
    tile: &BackTile,
    ch: usize,
    scratch: &mut BackScratch,
    out: &mut [f32],
    mut kernel: impl FnMut(&BackSplat, &mut BackScratch, &mut [f32]),
) {
    let stride = ISECT_FIXED + ch;
    let k_end = scratch.last.iter().copied().max().unwrap_or(0) as usize;
    for k in (0..k_end).rev() {
        let s = &tile.splats[k];
        let Some(fp) = scratch.geo.footprint(s, &tile.rect) else {
            continue;
        };
        let splat = BackSplat {
            s,
            f: &tile.features[k * ch..(k + 1) * ch],
            k: k as u32,
            fp,
        };
        kernel(&splat, scratch, &mut out[k * stride..(k + 1) * stride]);
    }
}

/// Sum of eight lanes in the tree the AVX2 kernel uses: (l0+l4 + l2+l6) + (l1+l5 + l3+l7).
#[inline(always)]
pub(super) fn lane_sum(v: &[f32; LANES]) -> f32 {
    let s = [v[0] + v[4], v[1] + v[5], v[2] + v[6], v[3] + v[7]];
    (s[0] + s[2]) + (s[1] + s[3])
}

fn backward_tile(tile: &BackTile, ch: usize, scratch: &mut BackScratch, out: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if tile.simd
        && ch <= super::blend_avx2::MAX_BACKWARD_CHANNELS
        && std::arch::is_x86_feature_detected!("avx2")
    {
        super::blend_avx2::backward_tile(tile, ch, scratch, out);
        return;
    }
    backward_tile_scalar(tile, ch, scratch, out);
}

/// The lane rules written out per pixel; the AVX2 kernel performs the same operations.
pub(super) fn backward_tile_scalar(
    tile: &BackTile,
    ch: usize,
    scratch: &mut BackScratch,
    out: &mut [f32],
) {
    let (plane, stride) = (scratch.geo.plane(), scratch.geo.stride);
    let mut acc_f = vec![[0.0f32; LANES]; ch];
    for_each_splat_back(tile, ch, scratch, out, |sp, sc, o| {
        let [ca, cb, cc] = sp.s.conic;
        // Lane sums of v_x, v_y, v_a, v_b, v_c, v_opacity.
        let mut acc = [[0.0f32; LANES]; ISECT_FIXED];
        acc_f.iter_mut().for_each(|a| *a = [0.0; LANES]);
        for gi in sp.fp.groups.clone() {
            for ly in sp.fp.rows.clone() {
                let base = ly * stride + gi * LANES;
                for i in 0..LANES {
                    let l = base + i;
                    let x = sc.geo.xs[gi * LANES + i];
                    let active = (x > sp.fp.xlo) & (x < sp.fp.xhi) & (sp.k < sc.last[l]);
                    let dx = sp.s.xy[0] - x;
                    let dy = sc.geo.row_dy[ly];
                    let sigma = sigma_at(ca, dx, sc.geo.row_c[ly], sc.geo.row_b[ly]);
                    let vis = exp_neg(-sigma);
                    let raw = sp.s.opacity * vis;
                    let alpha = raw.min(ALPHA_MAX);
                    if !(active & (sigma >= 0.0) & (alpha >= ALPHA_MIN)) {
                        continue;
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
    });
}
