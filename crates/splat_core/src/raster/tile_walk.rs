//! The per-tile state and the two splat walkers of the blending kernels: front to back for
//! the forward (`for_each_splat`), back to front for the backward (`for_each_splat_back`).
//! The scalar kernels (`forward_blend`, `backward_blend`) and the AVX2 ones (`blend_avx2`)
//! supply only the per-splat lane arithmetic; the walk itself is written once, here.

use std::sync::atomic::{AtomicU32, Ordering};

use super::prefetch::prefetch;
use super::tile_geometry::{
    BlendSplat, LaneFootprint, PixelFootprint, TileGeometry, TileList, TileRect,
};

/// Gradient values stored per intersection: xy (2), conic (3), opacity (1), features (ch).
pub const ISECT_FIXED: usize = 6;

/// Work a blending kernel did, counted only by the kernels' counting instances
/// (`COUNT = true`, run by `eval_count`); the timed instances carry no counter code.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EvalCount {
    /// Lane groups evaluated: each computes `LANES` pixel-splat alphas.
    pub groups: u64,
    /// Pixel-splat pairs that passed every test and were blended (forward) or
    /// differentiated (backward).
    pub blended: u64,
}

impl EvalCount {
    pub fn add(&mut self, other: EvalCount) {
        self.groups += other.groups;
        self.blended += other.blended;
    }
}

/// What one tile blends.
pub(super) struct TileInput<'a> {
    pub splats: &'a [BlendSplat],
    /// Each splat's footprint box in the tile (`tile_geometry::pixel_boxes`).
    pub boxes: &'a [PixelFootprint],
    pub features: &'a [f32],
    pub rect: TileRect,
    pub t_min: f32,
    /// Use the SIMD kernel when the CPU has one.
    pub simd: bool,
}

/// A thread's tile scratch and list kept in `slot` between tiles and calls (the blend
/// drivers keep one per thread), replaced by `make()` first if there is none or `fits`
/// rejects it (made for another tile size or channel count).
pub(super) fn kept_scratch<S>(
    slot: &mut Option<(S, TileList)>,
    fits: impl FnOnce(&S) -> bool,
    make: impl FnOnce() -> S,
) -> &mut (S, TileList) {
    if !slot.as_ref().is_some_and(|(s, _)| fits(s)) {
        *slot = Some((make(), TileList::default()));
    }
    slot.as_mut().expect("filled above")
}

/// Per-tile pixel state, structure of arrays with rows padded so that a lane group may
/// start at any column (`TileGeometry::new`).
pub(super) struct TileScratch {
    pub geo: TileGeometry,
    /// Transmittance, with its sign bit set once the pixel stopped (and on padding pixels):
    /// a live pixel's T is > 0, so the sign is a free stop flag, which the SIMD kernel
    /// turns into a lane mask with one shift instead of loading and storing a mask array
    /// per row. `write_state` and `write_image` clear it.
    pub trans: Vec<f32>,
    pub last: Vec<u32>,
    /// Planar features: channel c of pixel l at `c * geo.plane() + l`.
    pub feat: Vec<f32>,
    /// Pixels of the tile still blending.
    pub active: usize,
    pub evals: EvalCount,
}

impl TileScratch {
    pub(super) fn new(ts: usize, ch: usize) -> Self {
        let geo = TileGeometry::new(ts);
        let plane = geo.plane();
        Self {
            geo,
            trans: vec![1.0; plane],
            last: vec![0; plane],
            feat: vec![0.0; plane * ch],
            active: 0,
            evals: EvalCount::default(),
        }
    }

    /// Whether it was made for tiles of `ts` and `ch` channels.
    pub(super) fn fits(&self, ts: usize, ch: usize) -> bool {
        self.geo.ts == ts && self.feat.len() == self.geo.plane() * ch
    }

    pub(super) fn reset(&mut self, rect: &TileRect) {
        let (tw, th) = ((rect.x1 - rect.x0) as usize, (rect.y1 - rect.y0) as usize);
        self.trans.fill(-1.0);
        self.last.fill(0);
        self.feat.fill(0.0);
        for row in self.trans.chunks_exact_mut(self.geo.stride).take(th) {
            row[..tw].fill(1.0);
        }
        self.geo.set_tile(rect);
        self.active = tw * th;
    }

    /// Copies the tile's final transmittance and last-contributor counts into its slices
    /// of the tile-major state ([pixel in tile], rows of `ts`).
    pub(super) fn write_state(&self, rect: &TileRect, t_final: &mut [f32], last: &mut [u32]) {
        let (tw, th) = ((rect.x1 - rect.x0) as usize, (rect.y1 - rect.y0) as usize);
        for ly in 0..th {
            let (src, dst) = (ly * self.geo.stride, ly * self.geo.ts);
            for (d, t) in t_final[dst..dst + tw].iter_mut().zip(&self.trans[src..]) {
                *d = t.abs();
            }
            last[dst..dst + tw].copy_from_slice(&self.last[src..src + tw]);
        }
    }

    /// Writes the tile's pixels into its rows of the image: `render[ly]` is the tile's
    /// part of image row ly ([pixel][channel]), `alpha[ly]` likewise.
    pub(super) fn write_image(
        &self,
        ch: usize,
        render: &mut [&mut [f32]],
        alpha: &mut [&mut [f32]],
    ) {
        let plane = self.geo.plane();
        for (ly, (rrow, arow)) in render.iter_mut().zip(alpha.iter_mut()).enumerate() {
            let src = ly * self.geo.stride;
            for (a, t) in arow.iter_mut().zip(&self.trans[src..]) {
                *a = 1.0 - t.abs();
            }
            // Fixed-width pixels for the common widths: the compiler unrolls the channels.
            match ch {
                3 => interleave::<3>(rrow, &self.feat, plane, src),
                4 => interleave::<4>(rrow, &self.feat, plane, src),
                1 => interleave::<1>(rrow, &self.feat, plane, src),
                _ => {
                    for (lx, px) in rrow.chunks_exact_mut(ch).enumerate() {
                        for (c, v) in px.iter_mut().enumerate() {
                            *v = self.feat[c * plane + src + lx];
                        }
                    }
                }
            }
        }
    }
}

/// `row[lx][c] = planes[c * plane + src + lx]`: planar channels to interleaved pixels.
#[inline(always)]
fn interleave<const N: usize>(row: &mut [f32], planes: &[f32], plane: usize, src: usize) {
    for (lx, px) in row.chunks_exact_mut(N).enumerate() {
        for (c, v) in px.iter_mut().enumerate() {
            *v = planes[c * plane + src + lx];
        }
    }
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
    for (k, ((s, f), pixels)) in tile
        .splats
        .iter()
        .zip(tile.features.chunks_exact(ch))
        .zip(tile.boxes)
        .enumerate()
    {
        let Some(fp) = pixels.lanes(&tile.rect) else {
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

/// What one tile's backward reads: its list (front to back) and its pixels.
pub(super) struct BackTile<'a> {
    pub splats: &'a [BlendSplat],
    /// Each splat's footprint box in the tile (`tile_geometry::pixel_boxes`).
    pub boxes: &'a [PixelFootprint],
    pub features: &'a [f32],
    pub rect: TileRect,
    /// Use the SIMD kernel when the CPU has one.
    pub simd: bool,
}

/// Per-tile pixel state of the backward, structure of arrays with rows padded as the
/// forward's (padding pixels have `last` 0, so no splat touches them).
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
    pub evals: EvalCount,
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
            evals: EvalCount::default(),
        }
    }

    /// Whether it was made for tiles of `ts` and `ch` channels.
    pub(super) fn fits(&self, ts: usize, ch: usize) -> bool {
        self.geo.ts == ts && self.v_out.len() == self.geo.plane() * ch
    }

    /// Loads the tile's pixels (tile-major `t_final` / `last`, row-major gradients).
    #[allow(clippy::too_many_arguments)]
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

/// Where the backward kernels put a splat's gradient row (`ISECT_FIXED + ch` values).
pub(super) enum BackOut<'a> {
    /// Rows in list order: entry k's at `k * stride` (the kernel tests).
    #[cfg(test)]
    Rows(&'a mut [f32]),
    /// The camera's splat-major array (f32 bits, zeroed): entry k's row at `rows[k]`.
    /// Every row belongs to one intersection, hence to one tile, so tiles never store to
    /// the same row; relaxed atomics compile to plain stores and let tiles share the
    /// array without locks or unsafe code.
    Shared {
        grads: &'a [AtomicU32],
        rows: &'a [u32],
    },
}

impl BackOut<'_> {
    /// Asks for the cache lines of entry k's row ahead of `put`: rows land scattered over
    /// the splat-major array, and a store to a line not in cache stalls the kernel once
    /// the store buffer fills.
    #[inline(always)]
    fn prefetch(&self, k: usize, stride: usize) {
        match self {
            #[cfg(test)]
            BackOut::Rows(_) => {}
            BackOut::Shared { grads, rows } => {
                let r = rows[k] as usize * stride;
                if let (Some(first), Some(last)) = (grads.get(r), grads.get(r + stride - 1)) {
                    prefetch(first);
                    prefetch(last);
                }
            }
        }
    }

    #[inline(always)]
    fn put(&mut self, k: usize, row: &[f32]) {
        let stride = row.len();
        match self {
            #[cfg(test)]
            BackOut::Rows(out) => out[k * stride..(k + 1) * stride].copy_from_slice(row),
            BackOut::Shared { grads, rows } => {
                let r = rows[k] as usize;
                for (d, v) in grads[r * stride..(r + 1) * stride].iter().zip(row) {
                    d.store(v.to_bits(), Ordering::Relaxed);
                }
            }
        }
    }
}

/// How many entries ahead of the kernel the backward's walk prefetches the gradient rows.
const PREFETCH_AHEAD: usize = 2;

/// Walks the tile's list back to front from the last splat any pixel used, and calls
/// `kernel(splat, scratch, row)`; where it returns true (it wrote the splat's gradients
/// into `row`), puts the row into `out`. Rows it skips stay as they were (+0).
#[inline(always)]
pub(super) fn for_each_splat_back(
    tile: &BackTile,
    ch: usize,
    scratch: &mut BackScratch,
    out: &mut BackOut,
    mut kernel: impl FnMut(&BackSplat, &mut BackScratch, &mut [f32]) -> bool,
) {
    let mut row = vec![0.0f32; ISECT_FIXED + ch];
    let k_end = scratch.last.iter().copied().max().unwrap_or(0) as usize;
    for k in (0..k_end).rev() {
        if k >= PREFETCH_AHEAD {
            out.prefetch(k - PREFETCH_AHEAD, row.len());
        }
        let s = &tile.splats[k];
        let Some(fp) = scratch.geo.footprint(s, &tile.boxes[k], &tile.rect) else {
            continue;
        };
        let splat = BackSplat {
            s,
            f: &tile.features[k * ch..(k + 1) * ch],
            k: k as u32,
            fp,
        };
        if kernel(&splat, scratch, &mut row) {
            out.put(k, &row);
        }
    }
}
