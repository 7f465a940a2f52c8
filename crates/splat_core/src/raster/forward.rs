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

/// Slack in pixels around the exact alpha = 1/255 contour; only costs a few evaluations,
/// the per-pixel alpha test still decides.
const SPAN_SLACK: f32 = 0.01;

/// The pixels of a tile where a splat can reach alpha >= 1/255: the ellipse
/// q(d) <= qmax = 2 ln(255 opacity), visited row by row. Forward and backward share it, so
/// both visit exactly the same pixels.
#[derive(Debug, Clone, Copy)]
pub(super) struct PixelFootprint {
    /// b^2 - a c (< 0) and a * qmax: the row discriminant is k dy^2 + aq.
    k: f32,
    aq: f32,
    inv_a: f32,
    pub y0: u32,
    pub y1: u32,
}

impl PixelFootprint {
    #[inline(always)]
    pub fn new(s: &Splat, rect: &TileRect) -> Self {
        let [a, b, c] = s.conic;
        let k = b * b - a * c;
        let aq = a * s.qmax;
        let half = (aq / -k).sqrt();
        let (y0, y1) = pixel_span(s.xy[1] - half, s.xy[1] + half, rect.y0, rect.y1);
        Self {
            k,
            aq,
            inv_a: 1.0 / a,
            y0,
            y1,
        }
    }

    /// Pixel columns [x0, x1) of row `y` inside the footprint.
    #[inline(always)]
    pub fn row(&self, s: &Splat, y: u32, rect: &TileRect) -> (u32, u32) {
        let b = s.conic[1];
        let dy = s.xy[1] - (y as f32 + 0.5);
        let disc = self.k * dy * dy + self.aq;
        if disc.is_nan() || disc < 0.0 {
            return (0, 0);
        }
        let root = disc.sqrt();
        // dx = x_splat - x_pixel lies in [(-b dy - root) / a, (-b dy + root) / a].
        let lo = s.xy[0] - (root - b * dy) * self.inv_a;
        let hi = s.xy[0] + (root + b * dy) * self.inv_a;
        pixel_span(lo, hi, rect.x0, rect.x1)
    }
}

/// Pixel indices [i0, i1) whose centres (i + 0.5) lie in [lo, hi] (plus slack), clipped.
///
/// Clipping to integers commutes with ceil/floor, so the values are clipped first and
/// rounded by truncation: on baseline x86-64 `f32::ceil` is a libm call, and this runs for
/// every row of every splat (it was ~6% of the forward time at 100k Gaussians).
#[inline(always)]
fn pixel_span(lo: f32, hi: f32, min: u32, max: u32) -> (u32, u32) {
    // max/min return the non-NaN operand: NaN bounds clip to `min`, as before.
    let a = (lo - 0.5 - SPAN_SLACK).max(min as f32).min(max as f32);
    let a_int = a as u32;
    let a = a_int + ((a_int as f32) < a) as u32;
    // floor(v) + 1 clipped to [min, max] == floor(v clipped to [min - 1, max - 1]) + 1.
    let b = (hi - 0.5 + SPAN_SLACK)
        .max(min as f32 - 1.0)
        .min(max as f32 - 1.0);
    let b_int = b as i32;
    let b = (b_int - (b < b_int as f32) as i32 + 1) as u32;
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
    /// Splats and their features copied into tile-list order (tile-major, front to back),
    /// so blending reads memory sequentially instead of chasing indices.
    pub packed_splats: Vec<Splat>,
    pub packed_features: Vec<f32>,
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
    let packed_splats: Vec<Splat> = bins
        .isect_gid
        .par_iter()
        .map(|&g| splats[g as usize])
        .collect();
    let mut packed_features = vec![0.0f32; bins.n_intersections() * ch];
    packed_features
        .par_chunks_mut(ch)
        .zip(bins.isect_gid.par_iter())
        .for_each(|(f, &g)| f.copy_from_slice(&features[g as usize * ch..(g as usize + 1) * ch]));
    let mut out = Blended {
        features: vec![0.0; n_tiles * tp * ch],
        t_final: vec![1.0; n_tiles * tp],
        last: vec![0; n_tiles * tp],
        packed_splats,
        packed_features,
    };
    let (tile_splats, tile_features) = (&out.packed_splats, &out.packed_features);
    out.features
        .par_chunks_mut(tp * ch)
        .zip(out.t_final.par_chunks_mut(tp))
        .zip(out.last.par_chunks_mut(tp))
        .enumerate()
        .for_each(|(t, ((feat, trans), last))| {
            let rect = TileRect::new(t, bins, width, height);
            let range = bins.tile_range(t);
            let feats = &tile_features[range.start * ch..range.end * ch];
            let splats = &tile_splats[range];
            // Fixed channel counts get unrolled inner loops; 0 means "use ch".
            let run = match ch {
                1 => blend_tile::<1>,
                3 => blend_tile::<3>,
                4 => blend_tile::<4>,
                _ => blend_tile::<0>,
            };
            run(splats, feats, ch, rect, ts, t_min, feat, trans, last);
        });
    out
}

fn blend_tile<const CH: usize>(
    splats: &[Splat],
    features: &[f32],
    ch: usize,
    rect: TileRect,
    ts: usize,
    t_min: f32,
    feat: &mut [f32],
    trans: &mut [f32],
    last: &mut [u32],
) {
    let ch = if CH == 0 { ch } else { CH };
    let mut done = vec![false; ts * ts];
    let mut active = ((rect.x1 - rect.x0) * (rect.y1 - rect.y0)) as usize;
    for (k, (s, f)) in splats.iter().zip(features.chunks_exact(ch)).enumerate() {
        let fp = PixelFootprint::new(s, &rect);
        for y in fp.y0..fp.y1 {
            let row = (y - rect.y0) as usize * ts;
            let py = y as f32 + 0.5;
            let (xa, xb) = fp.row(s, y, &rect);
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
            // Each tile's part of an image row is contiguous in the tile-major buffers: one
            // copy per tile, not a (libc memmove) call per pixel.
            for x0 in (0..w).step_by(ts) {
                let n = ts.min(w - x0);
                let i = (tile_row + x0 / ts) * tp + ly;
                rrow[x0 * ch..(x0 + n) * ch]
                    .copy_from_slice(&blended.features[i * ch..(i + n) * ch]);
                for (a, t) in arow[x0..x0 + n].iter_mut().zip(&blended.t_final[i..i + n]) {
                    *a = 1.0 - t;
                }
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The plain form, with libm rounding.
    fn pixel_span_ref(lo: f32, hi: f32, min: u32, max: u32) -> (u32, u32) {
        let a = (lo - 0.5 - SPAN_SLACK)
            .ceil()
            .max(min as f32)
            .min(max as f32) as u32;
        let b = ((hi - 0.5 + SPAN_SLACK).floor() + 1.0)
            .max(min as f32)
            .min(max as f32) as u32;
        (a, b.max(a))
    }

    #[test]
    fn pixel_span_matches_ceil_floor_form() {
        let mut v = -70.0f32;
        while v < 140.0 {
            for &(min, max) in &[(0u32, 16u32), (16, 32), (48, 50), (0, 1)] {
                for &w in &[0.0f32, 0.3, 1.0, 2.51, 7.0, 40.0] {
                    assert_eq!(
                        pixel_span(v, v + w, min, max),
                        pixel_span_ref(v, v + w, min, max),
                        "{v} {w} {min} {max}"
                    );
                }
            }
            v += 0.0371;
        }
        // Exact integers and their neighbours, where rounding direction matters.
        for i in -3..40 {
            for d in [-1e-5f32, 0.0, 1e-5] {
                let v = i as f32 + 0.5 + SPAN_SLACK + d;
                let u = i as f32 + 0.5 - SPAN_SLACK + d;
                assert_eq!(pixel_span(v, u, 0, 32), pixel_span_ref(v, u, 0, 32));
                assert_eq!(
                    pixel_span(v, u + 3.0, 16, 32),
                    pixel_span_ref(v, u + 3.0, 16, 32)
                );
            }
        }
        for &bad in &[f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            assert_eq!(
                pixel_span(bad, 3.0, 16, 32),
                pixel_span_ref(bad, 3.0, 16, 32)
            );
            assert_eq!(
                pixel_span(20.0, bad, 16, 32),
                pixel_span_ref(20.0, bad, 16, 32)
            );
            assert_eq!(
                pixel_span(bad, bad, 16, 32),
                pixel_span_ref(bad, bad, 16, 32)
            );
        }
    }
}
