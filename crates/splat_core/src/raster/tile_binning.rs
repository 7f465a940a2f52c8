//! Which tiles each splat touches, and the per-tile lists sorted by depth.
//!
//! 1. Visible splats are ordered by (depth, index) once.
//! 2. Each splat lists the tiles of its footprint box that its footprint ellipse really
//!    touches (optional, `tile_ellipse`), in parallel, into one depth-major array.
//! 3. A stable counting sort by tile turns that into tile-major lists; because the input is
//!    depth-major, every tile's list comes out depth-sorted with no per-tile sort.
//!
//! The permutation of step 3 is kept: the backward pass uses it to sum each splat's
//! per-tile gradients in a fixed order without atomics.

use rayon::prelude::*;

use super::project::Splat;
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
    /// Intersections of `depth_order[i]` are depth-major positions
    /// `gauss_offsets[i]..gauss_offsets[i + 1]`.
    pub gauss_offsets: Vec<u32>,
    /// Depth-major position -> tile-major position.
    pub perm: Vec<u32>,
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

/// Minimum over [x0, x1] x [y0, y1] of q(d) = a dx^2 + 2 b dx dy + c dy^2 (a, c > 0).
fn min_quadratic_on_rect(conic: [f32; 3], x0: f32, x1: f32, y0: f32, y1: f32) -> f32 {
    let [a, b, c] = conic;
    if x0 <= 0.0 && 0.0 <= x1 && y0 <= 0.0 && 0.0 <= y1 {
        return 0.0;
    }
    let q = |x: f32, y: f32| a * x * x + 2.0 * b * x * y + c * y * y;
    // The minimum of a convex function over a rectangle not containing its minimiser lies
    // on the boundary: minimise along each edge (closed form, clamped).
    let (ba, bc) = (b / a, b / c);
    let on_vertical = |x: f32| q(x, (-bc * x).clamp(y0, y1));
    let on_horizontal = |y: f32| q((-ba * y).clamp(x0, x1), y);
    on_vertical(x0)
        .min(on_vertical(x1))
        .min(on_horizontal(y0))
        .min(on_horizontal(y1))
}

/// Whether the footprint ellipse q(d) <= extent^2 reaches a pixel centre of the tile.
fn ellipse_touches_tile(s: &Splat, tx: u32, ty: u32, tile_size: u32) -> bool {
    let ts = tile_size as f32;
    // Pixel centres of the tile, relative to the splat centre.
    let x0 = tx as f32 * ts + 0.5 - s.xy[0];
    let y0 = ty as f32 * ts + 0.5 - s.xy[1];
    let m = min_quadratic_on_rect(s.conic, x0, x0 + ts - 1.0, y0, y0 + ts - 1.0);
    // Small slack so rounding never drops a tile the exact test would keep.
    m <= s.extent * s.extent * (1.0 + 1e-4) + 1e-4
}

/// Calls `f(tile_id)` for every tile the splat touches, in row-major tile order.
fn for_each_tile(
    s: &Splat,
    tile_size: u32,
    tiles_x: u32,
    tiles_y: u32,
    ellipse: bool,
    mut f: impl FnMut(u32),
) {
    let [x0, x1, y0, y1] = tile_box(s, tile_size, tiles_x, tiles_y);
    // A box within one tile needs no test (keeping that tile is at worst conservative).
    let ellipse = ellipse && (x1 - x0) * (y1 - y0) > 1;
    for ty in y0..y1 {
        for tx in x0..x1 {
            if !ellipse || ellipse_touches_tile(s, tx, ty, tile_size) {
                f(ty * tiles_x + tx);
            }
        }
    }
}

/// Visible splats ordered front to back; ties broken by index, so the order is unique.
pub fn depth_order(splats: &[Splat]) -> Vec<u32> {
    // Depths of visible splats are >= near_plane > 0, so their bit patterns sort like the
    // values; (depth bits, index) packed in a u64 is a unique key.
    let mut keys: Vec<u64> = splats
        .par_iter()
        .enumerate()
        .filter(|(_, s)| s.visible())
        .map(|(g, s)| ((s.depth.to_bits() as u64) << 32) | g as u64)
        .collect();
    keys.par_sort_unstable();
    keys.into_iter().map(|k| k as u32).collect()
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

    // One gather into depth order (independent loads) so the two passes below read memory
    // sequentially instead of missing the cache on every splat.
    let sorted: Vec<Splat> = depth_order
        .par_iter()
        .map(|&g| splats[g as usize])
        .collect();
    let counts: Vec<u32> = sorted
        .par_iter()
        .map(|s| {
            let mut n = 0u32;
            for_each_tile(s, tile_size, tiles_x, tiles_y, ellipse, |_| n += 1);
            n
        })
        .collect();
    let mut gauss_offsets = Vec::with_capacity(counts.len() + 1);
    let mut total: u64 = 0;
    gauss_offsets.push(0u32);
    for &c in &counts {
        total += c as u64;
        if total > u32::MAX as u64 {
            return Err(CoreError::input(
                "more than 4 billion tile intersections: use fewer Gaussians or a smaller image",
            ));
        }
        gauss_offsets.push(total as u32);
    }

    // Depth-major tile ids: each splat fills its own slice.
    let mut isect_tile = vec![0u32; total as usize];
    let mut slices: Vec<&mut [u32]> = Vec::with_capacity(counts.len());
    let mut rest = isect_tile.as_mut_slice();
    for &c in &counts {
        let (head, tail) = rest.split_at_mut(c as usize);
        slices.push(head);
        rest = tail;
    }
    slices
        .into_par_iter()
        .zip(sorted.par_iter())
        .for_each(|(out, s)| {
            let mut i = 0;
            for_each_tile(s, tile_size, tiles_x, tiles_y, ellipse, |t| {
                out[i] = t;
                i += 1;
            });
        });

    // Stable counting sort by tile.
    let mut tile_offsets = vec![0u32; n_tiles + 1];
    for &t in &isect_tile {
        tile_offsets[t as usize + 1] += 1;
    }
    for t in 0..n_tiles {
        tile_offsets[t + 1] += tile_offsets[t];
    }
    let mut cursor = tile_offsets[..n_tiles].to_vec();
    let mut isect_gid = vec![0u32; isect_tile.len()];
    let mut perm = vec![0u32; isect_tile.len()];
    for (i, &g) in depth_order.iter().enumerate() {
        let range = gauss_offsets[i] as usize..gauss_offsets[i + 1] as usize;
        for p in range {
            let t = isect_tile[p] as usize;
            let k = cursor[t];
            cursor[t] += 1;
            perm[p] = k;
            isect_gid[k as usize] = g;
        }
    }
    Ok(TileBins {
        tile_size,
        tiles_x,
        tiles_y,
        tile_offsets,
        isect_gid,
        depth_order,
        gauss_offsets,
        perm,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn splat(x: f32, y: f32, r: f32, depth: f32, conic: [f32; 3], extent: f32) -> Splat {
        Splat {
            xy: [x, y],
            conic,
            opacity: 1.0,
            depth,
            radius: [r, r],
            extent,
            qmax: extent * extent,
        }
    }

    #[test]
    fn tiles_are_depth_sorted_and_permutation_is_consistent() {
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
        for (i, &g) in bins.depth_order.iter().enumerate() {
            for p in bins.gauss_offsets[i]..bins.gauss_offsets[i + 1] {
                assert_eq!(bins.isect_gid[bins.perm[p as usize] as usize], g);
            }
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
    fn min_quadratic_matches_brute_force() {
        let conic = [0.7f32, -0.4, 0.5];
        for &(x0, y0) in &[(-3.0f32, 2.0f32), (1.0, 1.0), (-10.0, -1.0), (2.0, -12.0)] {
            let (x1, y1) = (x0 + 5.0, y0 + 5.0);
            let m = min_quadratic_on_rect(conic, x0, x1, y0, y1);
            let mut brute = f32::INFINITY;
            for i in 0..=500 {
                for j in 0..=500 {
                    let x = x0 + (x1 - x0) * i as f32 / 500.0;
                    let y = y0 + (y1 - y0) * j as f32 / 500.0;
                    brute = brute.min(conic[0] * x * x + 2.0 * conic[1] * x * y + conic[2] * y * y);
                }
            }
            assert!(m <= brute + 1e-4 && m >= brute - 1e-2, "{m} vs {brute}");
        }
    }
}
