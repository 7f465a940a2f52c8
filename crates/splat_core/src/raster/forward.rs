//! Front-to-back alpha blending of the depth-sorted tile lists (rayon over tiles).
//!
//! Per pixel, exactly gsplat's classic rules: sigma = 0.5 (a dx^2 + c dy^2) + b dx dy,
//! alpha = min(0.99, opacity exp(-sigma)), skip sigma < 0 or alpha < 1/255, stop before the
//! splat that would bring T to <= t_min. Within a tile the loop runs splat-major and visits
//! only the pixels of the splat's footprint box; each pixel still sees its splats in depth
//! order, so the result equals the pixel-major loop bit for bit.
//!
//! The footprint is walked in lane groups of `LANES` adjacent pixels of a row, with
//! branch-free lane rules (masks instead of `continue`). `blend_avx2` runs them with AVX2
//! intrinsics when the CPU has AVX2 (checked at run time), `blend_tile_scalar` otherwise.
//! Both perform the same operations in the same order, without fused multiply-adds, so
//! every path gives the same bits (`kernel_tests`), and the backward pass, built the same
//! way, recomputes the same alphas.

use rayon::prelude::*;

use super::project::Splat;
use super::tile_binning::TileBins;
use super::{ALPHA_MAX, ALPHA_MIN};

/// exp(x) for x <= 0 (the kernels pass -sigma) from + and * only: Cody-Waite reduction and
/// Cephes' polynomial, accurate to 2 ulp. libm's `expf` is an opaque call: the blending loop
/// could not be vectorised around it, and the forward and backward passes must agree to
/// the bit. The polynomial is evaluated in Estrin's form, whose dependency chain is 4
/// operations shorter than Horner's: the blending loop is bound by this latency.
#[inline(always)]
pub(super) fn exp_neg(x: f32) -> f32 {
    // Below -87 the result would be subnormal; the callers discard it anyway (< 1/255).
    // Written as a comparison so that NaN maps to -87 in every lane. No upper clamp: x is
    // -sigma <= 0 up to rounding, and exact up to x = 88 anyway.
    let x = if x > -87.0 { x } else { -87.0 };
    // Adding 1.5 * 2^23 rounds x / ln 2 to the nearest integer n, left in the low bits.
    const ROUND: f32 = 12_582_912.0;
    let t = x * std::f32::consts::LOG2_E + ROUND;
    let n = t - ROUND;
    // ln 2 = C1 + C2 with C1 exact in 9 bits, so n * C1 is exact.
    let r = (x - n * 0.693_359_4) - n * -2.121_944_4e-4;
    let (r2, c) = (r * r, EXP_COEFFS);
    let r4 = r2 * r2;
    let p = (c[0] * r + c[1]) * r4 + ((c[2] * r + c[3]) * r2 + (c[4] * r + c[5]));
    let y = (p * r2 + r) + 1.0;
    // 2^n as bits: n is in [-126, 127], so the biased exponent stays in [1, 254].
    let n_int = t.to_bits().wrapping_sub(ROUND.to_bits());
    let scale = f32::from_bits(n_int.wrapping_add(127).wrapping_shl(23));
    y * scale
}

/// exp(r) = 1 + r + r^2 (c0 r^5 + c1 r^4 + ... + c5) on |r| <= ln(2) / 2 (Cephes expf).
pub(super) const EXP_COEFFS: [f32; 6] = [
    1.987_569_2e-4,
    1.398_199_9e-3,
    8.333_452e-3,
    4.166_579_6e-2,
    1.666_666_5e-1,
    0.5,
];

/// sigma at a pixel, from the row terms c dy^2 and b dy. Every kernel (forward, backward,
/// scalar, AVX2) evaluates exactly this expression, so all see the same alphas.
#[inline(always)]
pub(super) fn sigma_at(a: f32, dx: f32, c_dy2: f32, b_dy: f32) -> f32 {
    0.5 * (a * dx * dx + c_dy2) + dx * b_dy
}

/// Slack in pixels around the exact alpha = 1/255 contour; only costs a few evaluations,
/// the per-pixel alpha test still decides.
const SPAN_SLACK: f32 = 0.01;

/// The pixels of a tile a splat visits: the tile's part of the bounding box of the ellipse
/// q(d) <= qmax = 2 ln(255 opacity), outside which alpha < 1/255. The per-pixel alpha test
/// decides inside the box. Forward and backward share it, so both visit the same pixels.
///
/// A box, not the exact row spans of the ellipse: a span costs a square root per row, more
/// than the SIMD lanes it would save on splats a few pixels wide.
#[derive(Debug, Clone, Copy)]
pub(super) struct PixelFootprint {
    pub x0: u32,
    pub x1: u32,
    pub y0: u32,
    pub y1: u32,
}

impl PixelFootprint {
    #[inline(always)]
    pub fn new(s: &BlendSplat, rect: &TileRect) -> Self {
        let (x0, x1) = pixel_span(s.xy[0] - s.half[0], s.xy[0] + s.half[0], rect.x0, rect.x1);
        let (y0, y1) = pixel_span(s.xy[1] - s.half[1], s.xy[1] + s.half[1], rect.y0, rect.y1);
        Self { x0, x1, y0, y1 }
    }
}

/// What blending needs of a splat, copied per tile-list entry (32 bytes).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BlendSplat {
    pub xy: [f32; 2],
    pub conic: [f32; 3],
    pub opacity: f32,
    /// See `Splat::half`.
    pub half: [f32; 2],
}

impl From<&Splat> for BlendSplat {
    fn from(s: &Splat) -> Self {
        Self {
            xy: s.xy,
            conic: s.conic,
            opacity: s.opacity,
            half: s.half,
        }
    }
}

/// Pixel indices [i0, i1) whose centres (i + 0.5) lie in [lo, hi] (plus slack), clipped.
///
/// Clipping to integers commutes with ceil/floor, so the values are clipped first and
/// rounded by truncation: on baseline x86-64 `f32::ceil` is a libm call, and this runs
/// twice per (splat, tile) pair in the forward and again in the backward.
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

/// Blend results of one camera that the backward pass needs.
#[derive(Debug, Clone, Default)]
pub struct Blended {
    /// Final transmittance per pixel, [tile][pixel in tile]; 1 for padding pixels.
    pub t_final: Vec<f32>,
    /// Number of entries of the tile list the pixel went through up to its last
    /// contributing splat (0 = none).
    pub last: Vec<u32>,
}

/// One tile's splats and features copied out of the per-splat arrays in list order
/// (front to back), so that the kernels read them sequentially from L1 instead of chasing
/// indices. Gathered per tile, right before use, by forward and backward alike: a
/// tile-major copy of all lists would be written once and read back from memory.
#[derive(Debug, Default)]
pub(super) struct TileList {
    pub splats: Vec<BlendSplat>,
    /// [list entry][channel].
    pub features: Vec<f32>,
}

impl TileList {
    pub(super) fn gather(&mut self, gids: &[u32], splats: &[Splat], features: &[f32], ch: usize) {
        self.splats.clear();
        self.splats
            .extend(gids.iter().map(|&g| BlendSplat::from(&splats[g as usize])));
        self.features.clear();
        self.features.resize(gids.len() * ch, 0.0);
        // Fixed-width copies for the common widths: a slice copy of a runtime length is a
        // memcpy call per splat.
        match ch {
            3 => gather_rows::<3>(&mut self.features, features, gids),
            4 => gather_rows::<4>(&mut self.features, features, gids),
            1 => gather_rows::<1>(&mut self.features, features, gids),
            _ => {
                for (dst, &g) in self.features.chunks_exact_mut(ch).zip(gids) {
                    dst.copy_from_slice(&features[g as usize * ch..][..ch]);
                }
            }
        }
    }
}

/// `dst[k] = src[gids[k]]` for rows of `N` values.
fn gather_rows<const N: usize>(dst: &mut [f32], src: &[f32], gids: &[u32]) {
    for (d, &g) in dst.chunks_exact_mut(N).zip(gids) {
        let row: [f32; N] = src[g as usize * N..][..N].try_into().unwrap();
        d.copy_from_slice(&row);
    }
}

/// Pixels per lane group: eight f32 lanes fill an AVX2 register.
pub(super) const LANES: usize = 8;

/// Blends every tile of one camera into the row-major image `render` [H, W, ch] and
/// `alpha` [H, W] (both zero on entry).
pub fn blend(
    splats: &[Splat],
    features: &[f32],
    ch: usize,
    bins: &TileBins,
    width: u32,
    height: u32,
    t_min: f32,
    simd: bool,
    render: &mut [f32],
    alpha: &mut [f32],
) -> Blended {
    let ts = bins.tile_size as usize;
    let tp = ts * ts;
    let mut out = Blended {
        t_final: vec![1.0; bins.n_tiles() * tp],
        last: vec![0; bins.n_tiles() * tp],
    };
    // Tiles are the unit of parallel work (rows of tiles balance badly: a plant fills the
    // middle of the image), handed out a few at a time so that no thread idles while the
    // other finishes a long run of heavy tiles. Each tile writes its own slices;
    // `to_image` assembles the image.
    let mut tile_feat = vec![0.0f32; bins.n_tiles() * tp * ch];
    tile_feat
        .par_chunks_mut(tp * ch)
        .zip(out.t_final.par_chunks_mut(tp))
        .zip(out.last.par_chunks_mut(tp))
        .enumerate()
        .with_max_len(4)
        .for_each_init(
            || (TileScratch::new(ts, ch), TileList::default()),
            |(scratch, list), (t, ((feat, t_final), last))| {
                let range = bins.tile_range(t);
                if range.is_empty() {
                    return;
                }
                list.gather(&bins.isect_gid[range], splats, features, ch);
                let rect = TileRect::new(t, bins, width, height);
                let tile = TileInput {
                    splats: &list.splats,
                    features: &list.features,
                    rect,
                    t_min,
                    simd,
                };
                scratch.reset(&rect);
                blend_tile(&tile, ch, scratch);
                scratch.write(&rect, ch, feat, t_final, last);
            },
        );
    to_image(
        &tile_feat,
        &out.t_final,
        ch,
        bins,
        width,
        height,
        render,
        alpha,
    );
    out
}

/// What one tile blends.
pub(super) struct TileInput<'a> {
    pub splats: &'a [BlendSplat],
    pub features: &'a [f32],
    pub rect: TileRect,
    pub t_min: f32,
    /// Use the SIMD kernel when the CPU has one.
    pub simd: bool,
}

/// The geometry every lane kernel (forward and backward) reads: the row stride (rows padded
/// to whole lane groups), the pixel-centre x of each column of the current tile, and for
/// each footprint row of the current splat dy, c dy^2 and b dy.
pub(super) struct TileGeometry {
    pub stride: usize,
    pub ts: usize,
    pub xs: Vec<f32>,
    pub row_dy: Vec<f32>,
    pub row_c: Vec<f32>,
    pub row_b: Vec<f32>,
}

/// A splat's footprint in a tile: columns (relative to the tile) whose pixel centre lies
/// strictly between `xlo` and `xhi`, the lane groups covering them, and the rows.
pub(super) struct LaneFootprint {
    pub xlo: f32,
    pub xhi: f32,
    pub groups: std::ops::Range<usize>,
    pub rows: std::ops::Range<usize>,
}

impl TileGeometry {
    pub(super) fn new(ts: usize) -> Self {
        let stride = ts.div_ceil(LANES) * LANES;
        Self {
            stride,
            ts,
            xs: vec![0.0; stride],
            row_dy: vec![0.0; ts],
            row_c: vec![0.0; ts],
            row_b: vec![0.0; ts],
        }
    }

    /// Pixels per tile buffer (padded rows).
    pub fn plane(&self) -> usize {
        self.stride * self.ts
    }

    pub(super) fn set_tile(&mut self, rect: &TileRect) {
        for (i, x) in self.xs.iter_mut().enumerate() {
            *x = (rect.x0 as usize + i) as f32 + 0.5;
        }
    }

    /// The splat's footprint in the tile (None if it has no pixel there), with the row
    /// terms of its rows filled in.
    #[inline(always)]
    pub(super) fn footprint(&mut self, s: &BlendSplat, rect: &TileRect) -> Option<LaneFootprint> {
        let fp = PixelFootprint::new(s, rect);
        if fp.x0 >= fp.x1 || fp.y0 >= fp.y1 {
            return None;
        }
        let [_, b, c] = s.conic;
        let (lx0, lx1) = ((fp.x0 - rect.x0) as usize, (fp.x1 - rect.x0) as usize);
        let rows = (fp.y0 - rect.y0) as usize..(fp.y1 - rect.y0) as usize;
        for ly in rows.clone() {
            let dy = s.xy[1] - ((rect.y0 as usize + ly) as f32 + 0.5);
            self.row_dy[ly] = dy;
            self.row_c[ly] = c * dy * dy;
            self.row_b[ly] = b * dy;
        }
        Some(LaneFootprint {
            // Pixel centres are at integer + 0.5: these bounds select columns x0..x1.
            xlo: fp.x0 as f32,
            xhi: fp.x1 as f32,
            groups: lx0 / LANES..lx1.div_ceil(LANES),
            rows,
        })
    }
}

/// Per-tile pixel state, structure of arrays with rows padded to whole lane groups.
pub(super) struct TileScratch {
    pub geo: TileGeometry,
    pub trans: Vec<f32>,
    pub last: Vec<u32>,
    /// All ones while the pixel is blending (a SIMD mask), 0 once it stopped or if padding.
    pub live: Vec<u32>,
    /// Planar features: channel c of pixel l at `c * geo.plane() + l`.
    pub feat: Vec<f32>,
    /// Pixels of the tile still blending.
    pub active: usize,
}

impl TileScratch {
    pub(super) fn new(ts: usize, ch: usize) -> Self {
        let geo = TileGeometry::new(ts);
        let plane = geo.plane();
        Self {
            geo,
            trans: vec![1.0; plane],
            last: vec![0; plane],
            live: vec![0; plane],
            feat: vec![0.0; plane * ch],
            active: 0,
        }
    }

    pub(super) fn reset(&mut self, rect: &TileRect) {
        let (tw, th) = ((rect.x1 - rect.x0) as usize, (rect.y1 - rect.y0) as usize);
        self.trans.fill(1.0);
        self.last.fill(0);
        self.feat.fill(0.0);
        self.live.fill(0);
        for row in self.live.chunks_exact_mut(self.geo.stride).take(th) {
            row[..tw].fill(u32::MAX);
        }
        self.geo.set_tile(rect);
        self.active = tw * th;
    }

    /// Copies the tile's pixels into its slices of the tile-major buffers ([pixel][channel]
    /// for the features).
    pub(super) fn write(
        &self,
        rect: &TileRect,
        ch: usize,
        feat: &mut [f32],
        t_final: &mut [f32],
        last: &mut [u32],
    ) {
        let (tw, th) = ((rect.x1 - rect.x0) as usize, (rect.y1 - rect.y0) as usize);
        let plane = self.geo.plane();
        for ly in 0..th {
            let (src, dst) = (ly * self.geo.stride, ly * self.geo.ts);
            t_final[dst..dst + tw].copy_from_slice(&self.trans[src..src + tw]);
            last[dst..dst + tw].copy_from_slice(&self.last[src..src + tw]);
            let row = &mut feat[dst * ch..(dst + tw) * ch];
            for (lx, px) in row.chunks_exact_mut(ch).enumerate() {
                for (c, v) in px.iter_mut().enumerate() {
                    *v = self.feat[c * plane + src + lx];
                }
            }
        }
    }
}

/// Row-major image [H, W, ch] and alpha [H, W] from the tile-major buffers.
fn to_image(
    tile_feat: &[f32],
    t_final: &[f32],
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
            // copy per tile, not a call per pixel.
            for x0 in (0..w).step_by(ts) {
                let n = ts.min(w - x0);
                let i = (tile_row + x0 / ts) * tp + ly;
                rrow[x0 * ch..(x0 + n) * ch].copy_from_slice(&tile_feat[i * ch..(i + n) * ch]);
                for (a, t) in arow[x0..x0 + n].iter_mut().zip(&t_final[i..i + n]) {
                    *a = 1.0 - t;
                }
            }
        });
}

fn blend_tile(tile: &TileInput, ch: usize, scratch: &mut TileScratch) {
    #[cfg(target_arch = "x86_64")]
    if tile.simd && std::arch::is_x86_feature_detected!("avx2") {
        super::blend_avx2::blend_tile(tile, ch, scratch);
        return;
    }
    blend_tile_scalar(tile, ch, scratch);
}

/// One splat of a tile's list as the lane kernels see it.
pub(super) struct SplatInTile<'a> {
    pub s: &'a BlendSplat,
    /// Its features [ch].
    pub f: &'a [f32],
    /// 1 + its position in the tile list (the value `last` takes).
    pub k1: u32,
    pub fp: LaneFootprint,
}

/// Walks the tile's splats front to back and calls `kernel(splat, scratch)` for each splat
/// with pixels in the tile; the kernel blends the footprint and returns how many pixels
/// stopped. Ends when every pixel of the tile has stopped.
#[inline(always)]
pub(super) fn for_each_splat(
    tile: &TileInput,
    ch: usize,
    scratch: &mut TileScratch,
    mut kernel: impl FnMut(&SplatInTile, &mut TileScratch) -> u32,
) {
    for (k, (s, f)) in tile
        .splats
        .iter()
        .zip(tile.features.chunks_exact(ch))
        .enumerate()
    {
        let Some(fp) = scratch.geo.footprint(s, &tile.rect) else {
            continue;
        };
        let splat = SplatInTile {
            s,
            f,
            k1: k as u32 + 1,
            fp,
        };
        let stopped = kernel(&splat, scratch);
        scratch.active -= stopped as usize;
        if scratch.active == 0 {
            break;
        }
    }
}

/// The lane rules written out per pixel; the AVX2 kernel performs the same operations.
pub(super) fn blend_tile_scalar(tile: &TileInput, ch: usize, scratch: &mut TileScratch) {
    let (plane, stride) = (scratch.geo.plane(), scratch.geo.stride);
    let t_min = tile.t_min;
    for_each_splat(tile, ch, scratch, |sp, sc| {
        let [a, _, _] = sp.s.conic;
        let mut stopped = 0;
        for gi in sp.fp.groups.clone() {
            for ly in sp.fp.rows.clone() {
                let base = ly * stride + gi * LANES;
                // Pixels that already stopped cost nothing more.
                if sc.live[base..base + LANES].iter().all(|&l| l == 0) {
                    continue;
                }
                for i in 0..LANES {
                    let l = base + i;
                    let x = sc.geo.xs[gi * LANES + i];
                    let inside = (x > sp.fp.xlo) & (x < sp.fp.xhi) & (sc.live[l] != 0);
                    let dx = sp.s.xy[0] - x;
                    let sigma = sigma_at(a, dx, sc.geo.row_c[ly], sc.geo.row_b[ly]);
                    let alpha = (sp.s.opacity * exp_neg(-sigma)).min(ALPHA_MAX);
                    let ok = inside & (sigma >= 0.0) & (alpha >= ALPHA_MIN);
                    let t = sc.trans[l];
                    let next_t = t * (1.0 - alpha);
                    let stop = ok & (next_t <= t_min);
                    let add = ok & !stop;
                    let weight = if add { alpha * t } else { 0.0 };
                    for (c, &fc) in sp.f.iter().enumerate() {
                        sc.feat[c * plane + l] += weight * fc;
                    }
                    if add {
                        sc.trans[l] = next_t;
                        sc.last[l] = sp.k1;
                    }
                    if stop {
                        sc.live[l] = 0;
                        stopped += 1;
                    }
                }
            }
        }
        stopped
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_neg_is_accurate_and_total() {
        let mut worst = 0.0f64;
        let mut x = 0.0f32;
        while x > -87.0 {
            let rel = ((exp_neg(x) as f64) / (x as f64).exp() - 1.0).abs();
            worst = worst.max(rel);
            x -= 0.000_731;
        }
        // 2 ulp at 1 is 2.4e-7.
        assert!(worst < 2.4e-7, "worst relative error {worst:e}");
        assert_eq!(exp_neg(0.0), 1.0);
        assert_eq!(exp_neg(-0.0), 1.0);
        // NaN and far-negative inputs give finite values in [0, 1] (callers mask them).
        for v in [f32::NAN, f32::NEG_INFINITY, -1e30] {
            let e = exp_neg(v);
            assert!(e.is_finite() && (0.0..=1.0).contains(&e), "{v} -> {e}");
        }
        // Slightly positive x (-sigma after rounding) is still exp(x).
        assert!((exp_neg(1e-6) - 1.000_001).abs() < 2e-7);
    }

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
