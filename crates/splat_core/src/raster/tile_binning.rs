//! Which tiles each splat touches, and the per-tile lists sorted by depth.
//!
//! 1. Visible splats are ordered by (depth, index) once (`depth_sort`, a radix sort).
//! 2. Each splat lists the tiles of its footprint box that its footprint ellipse really
//!    touches (optional, `tile_ellipse`); fixed chunks of the depth-ordered splats do this
//!    in parallel and sort their pairs by tile (stable counting sort).
//! 3. Each tile concatenates the chunks' lists for it in chunk order; because the chunks
//!    are depth-ordered, every tile's list comes out depth-sorted with no per-tile sort.
//!
//! A splat's entries in the tile-major lists come in increasing tile order; the backward
//! pass sums its per-tile gradients in that fixed order, without atomics.

use rayon::prelude::*;

use super::buffers::filled;
use super::project::Splat;
use crate::memory::try_filled;
use crate::{CoreError, CoreResult};

/// Tile lists of one camera.
#[derive(Debug, Clone, Default)]
pub struct TileBins {
    pub tile_size: u32,
    pub tiles_x: u32,
    pub tiles_y: u32,
    /// Tile t's intersections are `isect_gid[tile_offsets[t]..tile_offsets[t + 1]]`.
    pub tile_offsets: Vec<u32>,
    /// Splat index of each intersection, tile-major, front to back within a tile.
    pub isect_gid: Vec<u32>,
    /// Visible splats, front to back.
    pub depth_order: Vec<u32>,
}

impl TileBins {
    pub fn n_tiles(&self) -> usize {
        (self.tiles_x * self.tiles_y) as usize
    }

    pub fn n_intersections(&self) -> usize {
        self.isect_gid.len()
    }

    pub fn tile_range(&self, t: usize) -> std::ops::Range<usize> {
        self.tile_offsets[t] as usize..self.tile_offsets[t + 1] as usize
    }
}

/// Inclusive-exclusive tile index range of a splat's footprint box, clipped to the image.
#[inline(always)]
fn tile_box(s: &Splat, tile_size: u32, tiles_x: u32, tiles_y: u32) -> [u32; 4] {
    let inv = 1.0 / tile_size as f32;
    // Clip first, then round: the values are small and non-negative, so truncation is floor
    // (and libm's floorf/ceilf are out-of-line calls on baseline x86-64).
    let lo = |v: f32, hi: u32| (v * inv).max(0.0).min(hi as f32) as u32;
    let up = |v: f32, hi: u32| {
        let x = (v * inv).max(0.0).min(hi as f32);
        let t = x as u32;
        t + (t as f32).lt(&x) as u32
    };
    [
        lo(s.xy[0] - s.radius[0], tiles_x),
        up(s.xy[0] + s.radius[0], tiles_x),
        lo(s.xy[1] - s.radius[1], tiles_y),
        up(s.xy[1] + s.radius[1], tiles_y),
    ]
}

/// The footprint ellipse q(d) = a dx^2 + 2 b dx dy + c dy^2 <= extent^2 (d = pixel - centre),
/// cut into horizontal bands: where does a band of pixel-centre rows meet it in x?
struct EllipseBands {
    /// 1 / a (a row's dx range is divided by a) and b.
    inv_a: f32,
    b: f32,
    /// a * E and a c - b^2, for the row discriminant a E - det dy^2.
    a_e: f32,
    det: f32,
    /// Half-height of the ellipse, and the dy of its leftmost (dy_left) and rightmost
    /// (-dy_left) points.
    half_y: f32,
    dy_left: f32,
}

impl EllipseBands {
    fn new(s: &Splat) -> Self {
        let [a, b, c] = s.conic;
        // Small slack so rounding never drops a tile the exact test would keep.
        let e = s.extent * s.extent * (1.0 + 1e-4) + 1e-4;
        let det = a * c - b * b;
        let e_det = e / det;
        let half_x = (c * e_det).sqrt();
        Self {
            inv_a: 1.0 / a,
            b,
            a_e: a * e,
            det,
            half_y: (a * e_det).sqrt(),
            dy_left: b * half_x / c,
        }
    }

    /// dx range (lo, hi) of the ellipse over rows dy in [d0, d1], and whether the band meets
    /// the ellipse at all (lo and hi mean nothing when it does not; they are NaN if the
    /// splat is degenerate). The left boundary of an ellipse is convex in dy, so its
    /// minimum over the band is at the leftmost point clamped into the band; likewise the
    /// right boundary's maximum. No branch: callers test tiles with masks.
    #[inline(always)]
    fn dx_range(&self, d0: f32, d1: f32) -> (f32, f32, bool) {
        let (d0, d1) = (d0.max(-self.half_y), d1.min(self.half_y));
        let root = |dy: f32| (self.a_e - self.det * dy * dy).max(0.0).sqrt();
        // max then min, not clamp: clamp panics on the empty bands that are masked out.
        let dy = self.dy_left.max(d0).min(d1);
        let lo = (-self.b * dy - root(dy)) * self.inv_a;
        let dy = (-self.dy_left).max(d0).min(d1);
        let hi = (-self.b * dy + root(dy)) * self.inv_a;
        // NaN (a degenerate splat) keeps its box.
        (lo, hi, (d0 <= d1) | d0.is_nan() | d1.is_nan())
    }
}

/// (tile, splat) pairs of one chunk, appended without a branch per pair: a slot is always
/// written and the length advances only if the pair is kept.
struct TilePairs {
    buf: Vec<(u32, u32)>,
    len: usize,
}

impl TilePairs {
    fn with_capacity(n: usize) -> Self {
        Self {
            buf: vec![(0, 0); n],
            len: 0,
        }
    }

    /// Room for `n` more pairs.
    #[inline(always)]
    fn reserve(&mut self, n: usize) {
        if self.len + n > self.buf.len() {
            self.buf
                .resize((self.len + n).max(2 * self.buf.len()), (0, 0));
        }
    }

    /// Appends (t, g) if `keep`; needs a reserved slot.
    #[inline(always)]
    fn push_if(&mut self, t: u32, g: u32, keep: bool) {
        self.buf[self.len] = (t, g);
        self.len += keep as usize;
    }

    fn as_slice(&self) -> &[(u32, u32)] {
        &self.buf[..self.len]
    }
}

/// A splat's tile box and, with the ellipse test on, its footprint ellipse's bands.
struct TileFootprint {
    tile_box: [u32; 4],
    bands: Option<EllipseBands>,
}

impl TileFootprint {
    /// No branch on the splat (the bands are computed even for boxes of one tile, which
    /// ignore them): run over a batch of splats before their tiles are listed, the
    /// divisions and square roots of many splats overlap instead of each waiting behind
    /// the mispredicted loop exits of the splat before it (binning 6.3 -> 5.7 ms on one
    /// thread at 100k splats).
    #[inline(always)]
    fn new(s: &Splat, tile_size: u32, tiles_x: u32, tiles_y: u32, ellipse: bool) -> Self {
        Self {
            tile_box: tile_box(s, tile_size, tiles_x, tiles_y),
            bands: ellipse.then(|| EllipseBands::new(s)),
        }
    }
}

/// Splats whose `TileFootprint`s are computed together before their tiles are listed.
const FOOTPRINT_BATCH: usize = 32;

/// Appends (tile, g) for every tile splat `s` touches, in row-major tile order.
#[cfg(test)]
fn push_tiles(
    s: &Splat,
    g: u32,
    tile_size: u32,
    tiles_x: u32,
    tiles_y: u32,
    ellipse: bool,
    pairs: &mut TilePairs,
) {
    let fp = TileFootprint::new(s, tile_size, tiles_x, tiles_y, ellipse);
    push_footprint(s, &fp, g, tile_size, tiles_x, pairs);
}

/// Appends (tile, g) for every tile of splat `s`'s footprint `fp`, in row-major tile order.
///
/// Every tile of the box is tested and appended without a branch: most splats span one
/// to four tiles, where loops over computed tile ranges and early exits would mispredict
/// on every splat.
#[inline(always)]
fn push_footprint(
    s: &Splat,
    fp: &TileFootprint,
    g: u32,
    tile_size: u32,
    tiles_x: u32,
    pairs: &mut TilePairs,
) {
    let [x0, x1, y0, y1] = fp.tile_box;
    pairs.reserve(((x1 - x0) * (y1 - y0)) as usize);
    // A box within one tile needs no test (keeping that tile is at worst conservative).
    let bands = fp.bands.as_ref().filter(|_| (x1 - x0) * (y1 - y0) > 1);
    let ts = tile_size as f32;
    for ty in y0..y1 {
        // Pixel-centre rows of the tile row, relative to the splat centre.
        let d0 = ty as f32 * ts + 0.5 - s.xy[1];
        let band = bands.map(|b| b.dx_range(d0, d0 + ts - 1.0));
        for tx in x0..x1 {
            let keep = band.is_none_or(|(lo, hi, meets)| {
                // Pixel-centre columns of the tile, relative to the splat centre. NaN
                // bounds keep the tile.
                let left = tx as f32 * ts + 0.5 - s.xy[0];
                meets & ((hi >= left) | hi.is_nan()) & ((lo <= left + ts - 1.0) | lo.is_nan())
            });
            pairs.push_if(ty * tiles_x + tx, g, keep);
        }
    }
}

/// Splats per chunk of the binning pass: at least `MIN_CHUNK`, and at most `MAX_CHUNKS`
/// chunks; each chunk holds an offset per tile, so chunks x tiles is also capped (tiny tiles
/// on a huge image get fewer, larger chunks).
const MIN_CHUNK: usize = 2048;
const MAX_CHUNKS: usize = 64;
const MAX_CHUNK_OFFSETS: usize = 1 << 24;

/// One chunk's (tile, splat) pairs as per-tile lists.
struct ChunkLists {
    /// Splat indices sorted by tile; tile t's are `gids[offsets[t]..offsets[t + 1]]`.
    gids: Vec<u32>,
    offsets: Vec<u32>,
}

impl ChunkLists {
    /// Stable counting sort of (tile, splat) pairs by tile.
    fn sorted_by_tile(pairs: &[(u32, u32)], n_tiles: usize) -> Self {
        let mut offsets = vec![0u32; n_tiles + 1];
        for &(t, _) in pairs {
            offsets[t as usize + 1] += 1;
        }
        for t in 0..n_tiles {
            offsets[t + 1] += offsets[t];
        }
        let mut cursor = offsets[..n_tiles].to_vec();
        let mut gids = vec![0u32; pairs.len()];
        for &(t, g) in pairs {
            let k = &mut cursor[t as usize];
            gids[*k as usize] = g;
            *k += 1;
        }
        Self { gids, offsets }
    }

    fn len(&self, t: usize) -> u32 {
        self.offsets[t + 1] - self.offsets[t]
    }

    fn list(&self, t: usize) -> &[u32] {
        &self.gids[self.offsets[t] as usize..self.offsets[t + 1] as usize]
    }
}

/// Builds the tile lists of one camera from its visible splats in depth order.
pub fn bin(
    splats: &[Splat],
    depth_order: Vec<u32>,
    width: u32,
    height: u32,
    tile_size: u32,
    ellipse: bool,
) -> CoreResult<TileBins> {
    let tiles_x = width.div_ceil(tile_size);
    let tiles_y = height.div_ceil(tile_size);
    let n_tiles = (tiles_x * tiles_y) as usize;

    // Each chunk of splats (fixed by N alone, so the result does not depend on the thread
    // count) copies its splats into depth order (independent loads, so that the two passes
    // over them read memory sequentially), lists its (tile, splat) pairs and sorts them by
    // tile, stably: within a tile they stay in depth order. Gathering per chunk rather
    // than into one array beforehand keeps each chunk's copy in its own core's cache and
    // saves a parallel pass (bin stage 6-10% faster at 2 threads, BENCHMARKS.md).
    let n_chunks = (MAX_CHUNK_OFFSETS / (n_tiles + 1)).clamp(1, MAX_CHUNKS);
    let chunk = depth_order.len().div_ceil(n_chunks).max(MIN_CHUNK);
    let chunks: Vec<ChunkLists> = depth_order
        .par_chunks(chunk)
        .map(|gs| {
            let ss: Vec<Splat> = gs.iter().map(|&g| splats[g as usize]).collect();
            let mut pairs = TilePairs::with_capacity(ss.len() * 2);
            for (ss, gs) in ss.chunks(FOOTPRINT_BATCH).zip(gs.chunks(FOOTPRINT_BATCH)) {
                let fps: [_; FOOTPRINT_BATCH] = std::array::from_fn(|i| {
                    ss.get(i)
                        .map(|s| TileFootprint::new(s, tile_size, tiles_x, tiles_y, ellipse))
                });
                for ((s, &g), fp) in ss.iter().zip(gs).zip(&fps) {
                    let fp = fp.as_ref().expect("one footprint per splat");
                    push_footprint(s, fp, g, tile_size, tiles_x, &mut pairs);
                }
            }
            ChunkLists::sorted_by_tile(pairs.as_slice(), n_tiles)
        })
        .collect();
    let total: usize = chunks.iter().map(|c| c.gids.len()).sum();
    if total > u32::MAX as usize {
        return Err(CoreError::input(
            "more than 4 billion tile intersections: use fewer Gaussians or a smaller image",
        ));
    }
    // Tile t's list is the concatenation of the chunks' lists for t, in chunk (= depth)
    // order; every tile gathers its own slice, in parallel.
    let mut tile_offsets = try_filled(n_tiles + 1, 0u32)?;
    for t in 0..n_tiles {
        let n: u32 = chunks.iter().map(|c| c.len(t)).sum();
        tile_offsets[t + 1] = tile_offsets[t] + n;
    }
    let mut isect_gid = filled(total, 0u32)?;
    let mut slices: Vec<&mut [u32]> = Vec::with_capacity(n_tiles);
    let mut rest = isect_gid.as_mut_slice();
    for t in 0..n_tiles {
        let (head, tail) = rest.split_at_mut((tile_offsets[t + 1] - tile_offsets[t]) as usize);
        slices.push(head);
        rest = tail;
    }
    slices.into_par_iter().enumerate().for_each(|(t, out)| {
        let mut at = 0;
        for c in &chunks {
            let list = c.list(t);
            out[at..at + list.len()].copy_from_slice(list);
            at += list.len();
        }
    });
    Ok(TileBins {
        tile_size,
        tiles_x,
        tiles_y,
        tile_offsets,
        isect_gid,
        depth_order,
    })
}

#[cfg(test)]
mod tests {
    use super::super::depth_sort::depth_order;
    use super::*;
    use crate::test_rng::Lcg;

    fn splat(x: f32, y: f32, r: f32, depth: f32, conic: [f32; 3], extent: f32) -> Splat {
        Splat {
            xy: [x, y],
            conic,
            opacity: 1.0,
            depth,
            radius: [r, r],
            extent,
            half: [r, r],
        }
    }

    #[test]
    fn tiles_are_depth_sorted_and_complete() {
        let iso = [1.0 / 25.0, 0.0, 1.0 / 25.0];
        let splats = vec![
            splat(20.0, 20.0, 15.0, 3.0, iso, 3.0),
            splat(24.0, 12.0, 15.0, 1.0, iso, 3.0),
            Splat::default(),
            splat(40.0, 40.0, 4.0, 2.0, iso, 3.0),
        ];
        let bins = bin(&splats, depth_order(&splats), 64, 64, 16, false).unwrap();
        assert_eq!(bins.depth_order, vec![1, 3, 0]);
        for t in 0..bins.n_tiles() {
            let ids = &bins.isect_gid[bins.tile_range(t)];
            for w in ids.windows(2) {
                assert!(splats[w[0] as usize].depth < splats[w[1] as usize].depth);
            }
        }
        // Every visible splat is listed in exactly the tiles of its box (no ellipse test).
        for (g, s) in splats.iter().enumerate() {
            let [x0, x1, y0, y1] = tile_box(s, 16, bins.tiles_x, bins.tiles_y);
            let want = if s.visible() {
                (x1 - x0) * (y1 - y0)
            } else {
                0
            };
            let got = bins.isect_gid.iter().filter(|&&i| i as usize == g).count();
            assert_eq!(got as u32, want, "splat {g}");
        }
    }

    #[test]
    fn ellipse_test_drops_corner_tiles_of_a_thin_diagonal_splat() {
        // A long thin ellipse along the diagonal: its box covers many tiles, the ellipse few.
        let (s_long, s_thin) = (40.0f32, 1.0f32);
        let (c, s) = (
            std::f32::consts::FRAC_1_SQRT_2,
            std::f32::consts::FRAC_1_SQRT_2,
        );
        let (a, b, cc) = (
            c * c / (s_long * s_long) + s * s / (s_thin * s_thin),
            c * s * (1.0 / (s_long * s_long) - 1.0 / (s_thin * s_thin)),
            s * s / (s_long * s_long) + c * c / (s_thin * s_thin),
        );
        let r = (3.0 * (cc / (a * cc - b * b)).sqrt()).ceil();
        let sp = splat(64.0, 64.0, r, 1.0, [a, b, cc], 3.0);
        let with = bin(&[sp], vec![0], 128, 128, 16, true)
            .unwrap()
            .n_intersections();
        let without = bin(&[sp], vec![0], 128, 128, 16, false)
            .unwrap()
            .n_intersections();
        assert!(with < without / 2, "{with} vs {without}");
        assert!(with >= 8);
    }

    #[test]
    fn ellipse_tiles_match_brute_force() {
        // Random ellipses: every tile with a pixel centre inside the ellipse is kept, and no
        // kept tile is farther than the slack from the ellipse (dense sampling of the tile's
        // pixel-centre rectangle).
        let mut rng = Lcg::new(7);
        let mut rnd = move || rng.uniform();
        let (ts, tiles) = (8u32, 12u32);
        for k in 0..600 {
            // Large ellipses (many tiles per row) and small ones (at most 2 x 2 tiles, like
            // most of a plant's).
            let size = if k % 2 == 0 { 12.0 } else { 1.2 };
            let (s1, s2) = (0.3 + size * rnd(), 0.3 + size * rnd());
            let th = std::f32::consts::PI * rnd();
            let (c, s) = (th.cos(), th.sin());
            let (ia, ib) = (1.0 / (s1 * s1), 1.0 / (s2 * s2));
            let conic = [
                c * c * ia + s * s * ib,
                c * s * (ia - ib),
                s * s * ia + c * c * ib,
            ];
            let e = 3.0f32;
            let sxx = conic[2] / (conic[0] * conic[2] - conic[1] * conic[1]);
            let syy = conic[0] / (conic[0] * conic[2] - conic[1] * conic[1]);
            let (x, y) = (96.0 * rnd(), 96.0 * rnd());
            let mut sp = splat(x, y, 0.0, 1.0, conic, e);
            sp.radius = [(e * sxx.sqrt()).ceil(), (e * syy.sqrt()).ceil()];
            let mut kept = vec![false; (tiles * tiles) as usize];
            let mut pairs = TilePairs::with_capacity(0);
            push_tiles(&sp, 0, ts, tiles, tiles, true, &mut pairs);
            for &(t, _) in pairs.as_slice() {
                kept[t as usize] = true;
            }
            let q = |dx: f32, dy: f32| {
                conic[0] * dx * dx + 2.0 * conic[1] * dx * dy + conic[2] * dy * dy
            };
            for t in 0..tiles * tiles {
                let (tx, ty) = (
                    (t % tiles) as f32 * ts as f32,
                    (t / tiles) as f32 * ts as f32,
                );
                let (mut inside_pixel, mut near) = (false, false);
                for i in 0..ts {
                    for j in 0..ts {
                        let (px, py) = (tx + i as f32 + 0.5, ty + j as f32 + 0.5);
                        inside_pixel |= q(px - x, py - y) <= e * e * 0.999;
                    }
                }
                for i in 0..=20 * (ts - 1) {
                    for j in 0..=20 * (ts - 1) {
                        let (px, py) = (tx + 0.5 + i as f32 / 20.0, ty + 0.5 + j as f32 / 20.0);
                        near |= q(px - x, py - y) <= e * e * 1.01 + 0.01;
                    }
                }
                let k = kept[t as usize];
                assert!(!inside_pixel || k, "tile {t} dropped");
                assert!(!k || near, "tile {t} kept but far");
            }
        }
    }
}
