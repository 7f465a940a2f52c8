//! Front-to-back alpha blending of the depth-sorted tile lists (rayon over tiles).
//!
//! Per pixel, exactly gsplat's classic rules: sigma = 0.5 (a dx^2 + c dy^2) + b dx dy,
//! alpha = min(0.99, opacity exp(-sigma)), skip sigma < 0 or alpha < 1/255, stop before the
//! splat that would bring T to <= t_min. Within a tile the loop runs splat-major and visits
//! only the pixels of the splat's footprint box; each pixel still sees its splats in depth
//! order, so the result equals the pixel-major loop bit for bit.
//!
//! The footprint is walked in lane groups of `LANES` adjacent pixels of a row, starting at
//! the footprint box's first column, with branch-free lane rules (masks instead of
//! `continue`). `blend_avx2` runs them with AVX2
//! intrinsics when the CPU has AVX2 (checked at run time), `blend_tile_scalar` otherwise.
//! Both perform the same operations in the same order, without fused multiply-adds, so
//! every path gives the same bits (`kernel_tests`), and the backward pass, built the same
//! way, recomputes the same alphas.

use rayon::prelude::*;

use super::buffers::filled;
use super::lanes::{exp_neg, sigma_at, LANES};
use super::options::{ALPHA_MAX, ALPHA_MIN};
use super::project::Splat;
use super::tile_binning::TileBins;
use super::tile_geometry::{pixel_boxes, BlendRecord, TileList, TileRect};
use super::tile_walk::{for_each_splat, kept_scratch, EvalCount, TileInput, TileScratch};
use crate::CoreResult;

/// Blend results of one camera that the backward pass needs.
#[derive(Debug, Clone, Default)]
pub struct Blended {
    /// Final transmittance per pixel, [tile][pixel in tile]; 1 for padding pixels.
    pub t_final: Vec<f32>,
    /// Number of entries of the tile list the pixel went through up to its last
    /// contributing splat (0 = none).
    pub last: Vec<u32>,
}

/// Blends every tile of one camera into the row-major image `render` [H, W, ch] and
/// `alpha` [H, W] (both zero on entry). With `count`, runs the kernels' counting instances
/// and returns their work (zero otherwise).
// Structure-of-arrays inputs and outputs, as the kernels read them; a struct would only
// rename them.
#[allow(clippy::too_many_arguments)]
pub fn blend(
    splats: &[Splat],
    features: &[f32],
    records: Option<&[BlendRecord]>,
    ch: usize,
    bins: &TileBins,
    width: u32,
    height: u32,
    t_min: f32,
    simd: bool,
    count: bool,
    render: &mut [f32],
    alpha: &mut [f32],
) -> CoreResult<(Blended, EvalCount)> {
    let ts = bins.tile_size as usize;
    let tp = ts * ts;
    let mut out = Blended {
        t_final: filled(bins.n_tiles() * tp, 1.0)?,
        last: filled(bins.n_tiles() * tp, 0)?,
    };
    // Each tile's rows of the image, so that tiles write the row-major image directly.
    let mut render_rows = tile_rows(render, ch, bins, width, height);
    let mut alpha_rows = tile_rows(alpha, 1, bins, width, height);
    // Tiles are the unit of parallel work (rows of tiles balance badly: a plant fills the
    // middle of the image), handed out a few at a time so that no thread idles while the
    // other finishes a long run of heavy tiles. Each tile writes its own slices.
    let totals = std::sync::Mutex::new(EvalCount::default());
    render_rows
        .par_chunks_mut(ts)
        .zip(alpha_rows.par_chunks_mut(ts))
        .zip(out.t_final.par_chunks_mut(tp))
        .zip(out.last.par_chunks_mut(tp))
        .enumerate()
        .with_max_len(4)
        .for_each(|(t, (((rrows, arows), t_final), last))| {
            SCRATCH.with_borrow_mut(|kept| {
                let (scratch, list) =
                    kept_scratch(kept, |sc| sc.fits(ts, ch), || TileScratch::new(ts, ch));
                let range = bins.tile_range(t);
                // An empty tile keeps the zero image and the initial state.
                if range.is_empty() {
                    return;
                }
                let gids = &bins.isect_gid[range];
                match records {
                    Some(records) => list.gather_records(gids, records, ch),
                    None => list.gather(gids, splats, features, ch),
                }
                let rect = TileRect::new(t, bins, width, height);
                blend_list(list, rect, ch, (t_min, simd), scratch, count);
                scratch.write_state(&rect, t_final, last);
                scratch.write_image(ch, rrows, arows);
                if count {
                    let mut t = totals.lock().unwrap_or_else(|e| e.into_inner());
                    t.add(std::mem::take(&mut scratch.evals));
                }
            })
        });
    let evals = totals.into_inner().unwrap_or_else(|e| e.into_inner());
    Ok((out, evals))
}

thread_local! {
    /// Each thread's tile scratch, kept between tiles and calls, as the backward's: built
    /// per rayon job (`for_each_init`), its allocation and first fill cost the blend stage
    /// about 2% (BENCHMARKS.md).
    static SCRATCH: std::cell::RefCell<Option<(TileScratch, TileList)>> =
        const { std::cell::RefCell::new(None) };
}

/// The row-major image [H, W, ch] cut into its tiles' rows: entry `t * ts + ly` is tile t's
/// part of its row ly (empty below the image's last row).
fn tile_rows<'a>(
    image: &'a mut [f32],
    ch: usize,
    bins: &TileBins,
    width: u32,
    height: u32,
) -> Vec<&'a mut [f32]> {
    let ts = bins.tile_size as usize;
    let (w, tiles_x) = (width as usize, bins.tiles_x as usize);
    let mut rows: Vec<&mut [f32]> = Vec::new();
    rows.resize_with(bins.n_tiles() * ts, Default::default);
    for (y, row) in image
        .chunks_exact_mut(w * ch)
        .take(height as usize)
        .enumerate()
    {
        let (ty, ly) = (y / ts, y % ts);
        for (tx, piece) in row.chunks_mut(ts * ch).enumerate() {
            rows[(ty * tiles_x + tx) * ts + ly] = piece;
        }
    }
    rows
}

/// Blends the gathered tile list `list` of the tile `rect` into `scratch` (reset first),
/// with the stop rule `t_min` and the SIMD kernel where `simd` allows it.
pub(super) fn blend_list(
    list: &mut TileList,
    rect: TileRect,
    ch: usize,
    (t_min, simd): (f32, bool),
    scratch: &mut TileScratch,
    count: bool,
) {
    pixel_boxes(&list.splats, &rect, &mut list.boxes);
    let tile = TileInput {
        splats: &list.splats,
        boxes: &list.boxes,
        features: &list.features,
        rect,
        t_min,
        simd,
    };
    scratch.reset(&rect);
    blend_tile(&tile, ch, scratch, count);
}

fn blend_tile(tile: &TileInput, ch: usize, scratch: &mut TileScratch, count: bool) {
    #[cfg(target_arch = "x86_64")]
    if tile.simd && std::arch::is_x86_feature_detected!("avx2") {
        use super::blend_avx2::blend_tile;
        match count {
            false => blend_tile::<false>(tile, ch, scratch),
            true => blend_tile::<true>(tile, ch, scratch),
        }
        return;
    }
    match count {
        false => blend_tile_scalar::<false>(tile, ch, scratch),
        true => blend_tile_scalar::<true>(tile, ch, scratch),
    }
}

/// The lane rules written out per pixel; the AVX2 kernel performs the same operations and
/// skips the same lane groups, so both count the same work.
pub(super) fn blend_tile_scalar<const COUNT: bool>(
    tile: &TileInput,
    ch: usize,
    scratch: &mut TileScratch,
) {
    let (plane, stride) = (scratch.geo.plane(), scratch.geo.stride);
    let t_min = tile.t_min;
    for_each_splat(tile, ch, scratch, |sp, sc| {
        let [a, b, c] = sp.s.conic;
        let mut stopped = 0;
        for gi in sp.fp.groups.clone() {
            for ly in sp.fp.rows.clone() {
                let col = sp.fp.col0 + gi * LANES;
                let base = ly * stride + col;
                let inside = |i: usize| {
                    let x = sc.geo.xs[col + i];
                    (x > sp.fp.xlo) & (x < sp.fp.xhi) & sc.trans[base + i].is_sign_positive()
                };
                // Pixels that already stopped cost nothing more.
                if !(0..LANES).any(inside) {
                    continue;
                }
                if COUNT {
                    sc.evals.groups += 1;
                }
                for i in 0..LANES {
                    let l = base + i;
                    let x = sc.geo.xs[col + i];
                    let inside = (x > sp.fp.xlo) & (x < sp.fp.xhi) & sc.trans[l].is_sign_positive();
                    let dx = sp.s.xy[0] - x;
                    let dy = sp.s.xy[1] - sc.geo.ys[ly];
                    let sigma = sigma_at(a, dx, c * dy * dy, b * dy);
                    let alpha = (sp.s.opacity * exp_neg(-sigma)).min(ALPHA_MAX);
                    let ok = inside & (sigma >= 0.0) & (alpha >= ALPHA_MIN);
                    let t = sc.trans[l];
                    let next_t = t * (1.0 - alpha);
                    let stop = ok & (next_t <= t_min);
                    let add = ok & !stop;
                    if COUNT {
                        sc.evals.blended += add as u64;
                    }
                    let weight = if add { alpha * t } else { 0.0 };
                    for (c, &fc) in sp.f.iter().enumerate() {
                        sc.feat[c * plane + l] += weight * fc;
                    }
                    if add {
                        sc.trans[l] = next_t;
                        sc.last[l] = sp.k1;
                    }
                    if stop {
                        sc.trans[l] = -t;
                        stopped += 1;
                    }
                }
            }
        }
        stopped
    });
}

/// The blending kernel this CPU runs with `simd` on: "avx2" or "scalar".
pub fn blend_kernel() -> &'static str {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        return "avx2";
    }
    "scalar"
}
