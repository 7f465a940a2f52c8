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
//! Each tile writes only its own slice of the intersection-gradient array, so tiles run in
//! parallel without locks or atomics; the caller sums a splat's intersections in a fixed
//! order (see `tile_binning`'s permutation).

use rayon::prelude::*;

use super::forward::{pixel_alpha, Blended, PixelFootprint, TileRect};
use super::project::Splat;
use super::tile_binning::TileBins;
use super::ALPHA_MAX;

/// Gradient values stored per intersection: xy (2), conic (3), opacity (1), features (ch).
pub const ISECT_FIXED: usize = 6;

/// Per-intersection gradients of one camera, tile-major like `TileBins::isect_gid`.
pub fn blend_backward(
    ch: usize,
    bins: &TileBins,
    blended: &Blended,
    width: u32,
    height: u32,
    v_render: &[f32],
    v_alpha: &[f32],
) -> Vec<f32> {
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
    slices.into_par_iter().enumerate().for_each(|(t, out)| {
        if out.is_empty() {
            return;
        }
        let rect = TileRect::new(t, bins, width, height);
        let range = bins.tile_range(t);
        let feats = &blended.packed_features[range.start * ch..range.end * ch];
        let splats = &blended.packed_splats[range];
        let tile = TilePixels {
            t_final: &blended.t_final[t * tp..(t + 1) * tp],
            last: &blended.last[t * tp..(t + 1) * tp],
        };
        let run = match ch {
            1 => backward_tile::<1>,
            3 => backward_tile::<3>,
            4 => backward_tile::<4>,
            _ => backward_tile::<0>,
        };
        run(
            splats, feats, ch, rect, ts, width, &tile, v_render, v_alpha, out,
        );
    });
    grads
}

struct TilePixels<'a> {
    t_final: &'a [f32],
    last: &'a [u32],
}

fn backward_tile<const CH: usize>(
    splats: &[Splat],
    features: &[f32],
    ch: usize,
    rect: TileRect,
    ts: usize,
    width: u32,
    tile: &TilePixels,
    v_render: &[f32],
    v_alpha: &[f32],
    out: &mut [f32],
) {
    let ch = if CH == 0 { ch } else { CH };
    let stride = ISECT_FIXED + ch;
    let mut trans = tile.t_final.to_vec();
    let mut buf = vec![0.0f32; ts * ts * ch];
    let mut v_f = vec![0.0f32; ch];
    let k_end = tile.last.iter().copied().max().unwrap_or(0) as usize;
    for k in (0..k_end).rev() {
        let s = &splats[k];
        let f = &features[k * ch..(k + 1) * ch];
        let fp = PixelFootprint::new(s, &rect);
        let [ca, cb, cc] = s.conic;
        let (mut v_x, mut v_y, mut v_a, mut v_b, mut v_c, mut v_o) =
            (0.0f32, 0.0, 0.0, 0.0, 0.0, 0.0);
        v_f.fill(0.0);
        for y in fp.y0..fp.y1 {
            let row = (y - rect.y0) as usize * ts;
            let py = y as f32 + 0.5;
            for x in fp.x0..fp.x1 {
                let l = row + (x - rect.x0) as usize;
                if k >= tile.last[l] as usize {
                    continue;
                }
                let Some(pa) = pixel_alpha(s, x as f32 + 0.5, py) else {
                    continue;
                };
                let pix = y as usize * width as usize + x as usize;
                let v_out = &v_render[pix * ch..(pix + 1) * ch];
                let ra = 1.0 / (1.0 - pa.alpha).max(1e-6);
                let t_k = trans[l] * ra;
                let fac = pa.alpha * t_k;
                let b = &mut buf[l * ch..(l + 1) * ch];
                let mut v_al = v_alpha[pix] * tile.t_final[l] * ra;
                for c in 0..ch {
                    v_f[c] += fac * v_out[c];
                    v_al += (f[c] * t_k - b[c] * ra) * v_out[c];
                    b[c] += f[c] * fac;
                }
                trans[l] = t_k;
                if pa.raw <= ALPHA_MAX {
                    let v_sigma = -pa.raw * v_al;
                    v_a += 0.5 * v_sigma * pa.dx * pa.dx;
                    v_b += v_sigma * pa.dx * pa.dy;
                    v_c += 0.5 * v_sigma * pa.dy * pa.dy;
                    v_x += v_sigma * (ca * pa.dx + cb * pa.dy);
                    v_y += v_sigma * (cb * pa.dx + cc * pa.dy);
                    v_o += pa.vis * v_al;
                }
            }
        }
        let o = &mut out[k * stride..(k + 1) * stride];
        o[..ISECT_FIXED].copy_from_slice(&[v_x, v_y, v_a, v_b, v_c, v_o]);
        o[ISECT_FIXED..].copy_from_slice(&v_f);
    }
}
