//! Front-to-back alpha blending of the depth-sorted tile lists (rayon over tiles).
//!
//! Per pixel, exactly gsplat's classic rules: sigma = 0.5 (a dx^2 + c dy^2) + b dx dy,
//! alpha = min(0.99, opacity exp(-sigma)), skip sigma < 0 or alpha < 1/255, stop before the
//! splat that would bring T to <= t_min. Within a tile the loop runs splat-major and visits
//! only the pixels of the splat's footprint box (plus one pixel of slack); each pixel still
//! sees its splats in depth order, so the result equals the pixel-major loop bit for bit.
//! Tile buffers are tile-major; `to_image` converts to row-major images at the end.

use rayon::prelude::*;

use super::project::Splat;
use super::tile_binning::TileBins;
use super::{ALPHA_MAX, ALPHA_MIN};

/// Per-pixel blend quantities of one splat, shared with the backward pass so both see the
/// same floats.
#[derive(Debug, Clone, Copy)]
pub(super) struct PixelAlpha {
    pub alpha: f32,
    /// opacity * exp(-sigma) before the 0.99 clamp.
    pub raw: f32,
    pub vis: f32,
    pub dx: f32,
    pub dy: f32,
}

#[inline(always)]
pub(super) fn pixel_alpha(s: &Splat, px: f32, py: f32) -> Option<PixelAlpha> {
    let dx = s.xy[0] - px;
    let dy = s.xy[1] - py;
    let [a, b, c] = s.conic;
    let sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy;
    if sigma < 0.0 {
        return None;
    }
    let vis = (-sigma).exp();
    let raw = s.opacity * vis;
    let alpha = raw.min(ALPHA_MAX);
    if alpha < ALPHA_MIN {
        return None;
    }
    Some(PixelAlpha {
        alpha,
        raw,
        vis,
        dx,
        dy,
    })
}

/// Pixel range [lo, hi) along one axis of a tile covered by a splat's box (with slack).
#[inline(always)]
pub(super) fn box_range(centre: f32, radius: f32, lo: u32, hi: u32) -> (u32, u32) {
    let a = (centre - radius - 1.0)
        .floor()
        .max(lo as f32)
        .min(hi as f32) as u32;
    let b = (centre + radius + 1.0).ceil().max(lo as f32).min(hi as f32) as u32;
    (a, b.max(a))
}

/// Geometry of one tile: its pixel rectangle clipped to the image.
#[derive(Debug, Clone, Copy)]
pub(super) struct TileRect {
    pub x0: u32,
    pub y0: u32,
    pub x1: u32,
    pub y1: u32,
}

impl TileRect {
    pub fn new(t: usize, bins: &TileBins, width: u32, height: u32) -> Self {
        let ts = bins.tile_size;
        let (tx, ty) = (t as u32 % bins.tiles_x, t as u32 / bins.tiles_x);
        Self {
            x0: tx * ts,
            y0: ty * ts,
            x1: ((tx + 1) * ts).min(width),
            y1: ((ty + 1) * ts).min(height),
        }
    }
}

/// Tile-major blend results of one camera.
#[derive(Debug, Clone, Default)]
pub struct Blended {
    /// Accumulated features, [tile][pixel in tile][channel].
    pub features: Vec<f32>,
    /// Final transmittance per pixel, [tile][pixel in tile]; 1 for padding pixels.
    pub t_final: Vec<f32>,
    /// Number of entries of the tile list the pixel went through up to its last
    /// contributing splat (0 = none).
    pub last: Vec<u32>,
}

/// Blends every tile of one camera.
pub fn blend(
    splats: &[Splat],
    features: &[f32],
    ch: usize,
    bins: &TileBins,
    width: u32,
    height: u32,
    t_min: f32,
) -> Blended {
    let ts = bins.tile_size as usize;
    let tp = ts * ts;
    let n_tiles = bins.n_tiles();
    let mut out = Blended {
        features: vec![0.0; n_tiles * tp * ch],
        t_final: vec![1.0; n_tiles * tp],
        last: vec![0; n_tiles * tp],
    };
    out.features
        .par_chunks_mut(tp * ch.max(1))
        .zip(out.t_final.par_chunks_mut(tp))
        .zip(out.last.par_chunks_mut(tp))
        .enumerate()
        .for_each(|(t, ((feat, trans), last))| {
            let rect = TileRect::new(t, bins, width, height);
            let ids = &bins.isect_gid[bins.tile_range(t)];
            blend_tile(
                splats, features, ch, ids, rect, ts, t_min, feat, trans, last,
            );
        });
    out
}

fn blend_tile(
    splats: &[Splat],
    features: &[f32],
    ch: usize,
    ids: &[u32],
    rect: TileRect,
    ts: usize,
    t_min: f32,
    feat: &mut [f32],
    trans: &mut [f32],
    last: &mut [u32],
) {
    let mut done = vec![false; ts * ts];
    let mut active = ((rect.x1 - rect.x0) * (rect.y1 - rect.y0)) as usize;
    for (k, &g) in ids.iter().enumerate() {
        let s = &splats[g as usize];
        let f = &features[g as usize * ch..(g as usize + 1) * ch];
        let (xa, xb) = box_range(s.xy[0], s.radius[0], rect.x0, rect.x1);
        let (ya, yb) = box_range(s.xy[1], s.radius[1], rect.y0, rect.y1);
        for y in ya..yb {
            let row = (y - rect.y0) as usize * ts;
            let py = y as f32 + 0.5;
            for x in xa..xb {
                let l = row + (x - rect.x0) as usize;
                if done[l] {
                    continue;
                }
                let Some(pa) = pixel_alpha(s, x as f32 + 0.5, py) else {
                    continue;
                };
                let t = trans[l];
                let next_t = t * (1.0 - pa.alpha);
                if next_t <= t_min {
                    done[l] = true;
                    active -= 1;
                    continue;
                }
                let w = pa.alpha * t;
                for (o, v) in feat[l * ch..(l + 1) * ch].iter_mut().zip(f) {
                    *o += w * v;
                }
                trans[l] = next_t;
                last[l] = k as u32 + 1;
            }
        }
        if active == 0 {
            break;
        }
    }
}

/// Row-major image [H, W, ch] and alpha [H, W] from tile-major buffers.
pub fn to_image(
    blended: &Blended,
    ch: usize,
    bins: &TileBins,
    width: u32,
    height: u32,
    render: &mut [f32],
    alpha: &mut [f32],
) {
    let ts = bins.tile_size as usize;
    let tp = ts * ts;
    let w = width as usize;
    render
        .par_chunks_mut((w * ch).max(1))
        .zip(alpha.par_chunks_mut(w.max(1)))
        .take(height as usize)
        .enumerate()
        .for_each(|(y, (rrow, arow))| {
            let tile_row = (y / ts) * bins.tiles_x as usize;
            let ly = (y % ts) * ts;
            for x in 0..w {
                let i = (tile_row + x / ts) * tp + ly + x % ts;
                arow[x] = 1.0 - blended.t_final[i];
                rrow[x * ch..(x + 1) * ch].copy_from_slice(&blended.features[i * ch..(i + 1) * ch]);
            }
        });
}
