//! Where a splat lands in a tile: the tile's pixel rectangle, the splat's footprint box in it
//! (shared by forward and backward, so both visit the same pixels), the per-tile copy of the
//! splats and features, and the row geometry the lane kernels read.

use rayon::prelude::*;

use super::lanes::LANES;
use super::project::Splat;
use super::tile_binning::TileBins;

/// Slack in pixels around the exact alpha = 1/255 contour; only costs a few evaluations,
/// the per-pixel alpha test still decides.
const SPAN_SLACK: f32 = 0.01;

/// Relative widening of the ellipse for the per-group rows (on top of `SPAN_SLACK`): the
/// conic and the box half-sizes come from separately rounded f32 arithmetic, and the
/// boundary's square root magnifies their disagreement near the ellipse's tips.
const SPAN_WIDEN: f32 = 1e-3;
const WIDEN: f32 = (1.0 + SPAN_WIDEN) * (1.0 + SPAN_WIDEN);

/// The pixels of a tile a splat visits: the tile's part of the bounding box of the ellipse
/// q(d) <= qmax = 2 ln(255 opacity), outside which alpha < 1/255. The per-pixel alpha test
/// decides inside the box. Forward and backward share it; the backward also trims each
/// lane group's rows to the ellipse (`TileGeometry::footprint`), the forward does not
/// (`PixelFootprint::lanes` only): trimming (`set_group_rows`: a division and square roots
/// per pair) cost the forward more than the lane groups it saved on the bench scene, and
/// the forward kernel computes its row terms itself, next to the exp chain they hide
/// behind. The trimmed rows hold only pixels the alpha test rejects (tested), so both blend
/// the same pixel-splat pairs.
///
/// A box, not the exact row spans of the ellipse: a span costs a square root per row, more
/// than the SIMD lanes it would save on splats a few pixels wide.
#[derive(Debug, Clone, Copy, Default)]
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

    /// The box's columns, lane groups and rows in the tile (the forward's walk: nothing per
    /// group or per row); None if it is empty.
    ///
    /// Lane groups start at the box's first column, not at multiples of LANES: a box up to
    /// LANES wide is one group wherever it lies. On the bench scene that is 9% fewer
    /// evaluations in the forward, and in the backward 7.5% fewer and fewer boxes whose
    /// rows are trimmed per group (backward 5% faster interleaved, same bits).
    #[inline(always)]
    pub(super) fn lanes(&self, rect: &TileRect) -> Option<LaneFootprint> {
        if self.x0 >= self.x1 || self.y0 >= self.y1 {
            return None;
        }
        Some(LaneFootprint {
            // Pixel centres are at integer + 0.5: these bounds select columns x0..x1.
            xlo: self.x0 as f32,
            xhi: self.x1 as f32,
            col0: (self.x0 - rect.x0) as usize,
            groups: 0..((self.x1 - self.x0) as usize).div_ceil(LANES),
            rows: (self.y0 - rect.y0) as usize..(self.y1 - rect.y0) as usize,
        })
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

/// Feature channels a `BlendRecord` holds; wider features are gathered from their own array.
pub const RECORD_CHANNELS: usize = 8;

/// A splat and its features in one 64-byte cache line: what the forward's tile lists copy
/// per entry. Read in list order they are scattered over memory, so one line per entry
/// instead of a splat and a feature row (two to three lines) is most of the gather's cost.
#[derive(Debug, Clone, Copy, Default)]
#[repr(C, align(64))]
pub struct BlendRecord {
    pub splat: BlendSplat,
    pub features: [f32; RECORD_CHANNELS],
}

/// One record per splat (index order); None if the features are wider than a record.
pub fn blend_records(splats: &[Splat], features: &[f32], ch: usize) -> Option<Vec<BlendRecord>> {
    if ch > RECORD_CHANNELS || ch == 0 {
        return None;
    }
    Some(
        splats
            .par_iter()
            .zip(features.par_chunks_exact(ch))
            .map(|(s, f)| {
                let mut features = [0.0; RECORD_CHANNELS];
                features[..ch].copy_from_slice(f);
                BlendRecord {
                    splat: BlendSplat::from(s),
                    features,
                }
            })
            .collect(),
    )
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

/// One tile's splats and features copied out of the per-splat arrays in list order
/// (front to back), so that the kernels read them sequentially from L1 instead of chasing
/// indices. Gathered per tile, right before use, by forward and backward alike: a
/// tile-major copy of all lists would be written once and read back from memory.
#[derive(Debug, Default)]
pub(super) struct TileList {
    pub splats: Vec<BlendSplat>,
    /// The footprint box of each entry in the tile (`pixel_boxes`).
    pub boxes: Vec<PixelFootprint>,
    /// [list entry][channel].
    pub features: Vec<f32>,
}

/// The footprint boxes of `splats` in the tile `rect`, in one pass over the freshly
/// gathered list ahead of the blending loops (forward and backward): inside the loop, the
/// box arithmetic sat between the kernel calls; out of it, the forward's blend stage is
/// 3-5% faster (interleaved, both scenes, 1 and 2 threads), with the same bits.
pub(super) fn pixel_boxes(splats: &[BlendSplat], rect: &TileRect, boxes: &mut Vec<PixelFootprint>) {
    boxes.clear();
    boxes.extend(splats.iter().map(|s| PixelFootprint::new(s, rect)));
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

impl TileList {
    /// `gather` from the splats' records.
    pub(super) fn gather_records(&mut self, gids: &[u32], records: &[BlendRecord], ch: usize) {
        self.splats.clear();
        self.features.clear();
        match ch {
            3 => self.gather_record_rows::<3>(gids, records),
            4 => self.gather_record_rows::<4>(gids, records),
            1 => self.gather_record_rows::<1>(gids, records),
            _ => {
                for &g in gids {
                    let r = &records[g as usize];
                    self.splats.push(r.splat);
                    self.features.extend_from_slice(&r.features[..ch]);
                }
            }
        }
    }

    fn gather_record_rows<const N: usize>(&mut self, gids: &[u32], records: &[BlendRecord]) {
        self.splats
            .extend(gids.iter().map(|&g| records[g as usize].splat));
        self.features.resize(gids.len() * N, 0.0);
        for (d, &g) in self.features.chunks_exact_mut(N).zip(gids) {
            let row: [f32; N] = records[g as usize].features[..N].try_into().unwrap();
            d.copy_from_slice(&row);
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

/// The geometry every lane kernel (forward and backward) reads: the row stride (rows padded
/// so that a lane group may start at any column), the pixel-centre x and y of each column
/// and row of the current tile; for the backward also, for each footprint row of the
/// current splat dy, c dy^2 and b dy, and for each of its lane groups the rows where the
/// splat's ellipse meets the group's columns.
pub(super) struct TileGeometry {
    pub stride: usize,
    pub ts: usize,
    pub xs: Vec<f32>,
    /// Pixel-centre y of each row of the current tile.
    pub ys: Vec<f32>,
    pub row_dy: Vec<f32>,
    pub row_c: Vec<f32>,
    pub row_b: Vec<f32>,
    pub group_rows: Vec<std::ops::Range<usize>>,
}

/// A splat's footprint in a tile: columns (relative to the tile) whose pixel centre lies
/// strictly between `xlo` and `xhi`, and the lane groups covering them (each group's rows
/// are in `TileGeometry::group_rows`).
pub(super) struct LaneFootprint {
    pub xlo: f32,
    pub xhi: f32,
    /// Lane group g covers the columns `col0 + g * LANES ..` of the tile.
    pub col0: usize,
    pub groups: std::ops::Range<usize>,
    /// Rows (relative to the tile) of the footprint box.
    pub rows: std::ops::Range<usize>,
}

impl TileGeometry {
    /// Rows padded so that a lane group may start at any column of the tile
    /// (`PixelFootprint::lanes`).
    pub(super) fn new(ts: usize) -> Self {
        let stride = (ts + LANES - 1).div_ceil(LANES) * LANES;
        Self {
            stride,
            ts,
            xs: vec![0.0; stride],
            ys: vec![0.0; ts],
            row_dy: vec![0.0; ts],
            row_c: vec![0.0; ts],
            row_b: vec![0.0; ts],
            group_rows: vec![0..0; stride / LANES],
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
        for (i, y) in self.ys.iter_mut().enumerate() {
            *y = (rect.y0 as usize + i) as f32 + 0.5;
        }
    }

    /// The footprint of splat `s` with box `fp` in the tile (None if it has no pixel
    /// there), with each lane group's rows and the row terms of its rows filled in (the
    /// backward's walk).
    #[inline(always)]
    pub(super) fn footprint(
        &mut self,
        s: &BlendSplat,
        fp: &PixelFootprint,
        rect: &TileRect,
    ) -> Option<LaneFootprint> {
        let lanes = fp.lanes(rect)?;
        let [_, b, c] = s.conic;
        for ly in lanes.rows.clone() {
            let dy = s.xy[1] - ((rect.y0 as usize + ly) as f32 + 0.5);
            self.row_dy[ly] = dy;
            self.row_c[ly] = c * dy * dy;
            self.row_b[ly] = b * dy;
        }
        if lanes.groups.len() == 1 {
            self.group_rows[lanes.groups.start] = lanes.rows.clone();
        } else {
            self.set_group_rows(
                s,
                rect,
                fp,
                lanes.col0,
                lanes.groups.clone(),
                lanes.rows.clone(),
            );
        }
        Some(lanes)
    }

    /// For a footprint wider than one lane group: the rows of each group's columns that
    /// the ellipse of the footprint box meets (with the box's slack), so the kernels skip
    /// the lane vectors whose pixels all lie outside it, where alpha < 1/255 anyway.
    ///
    /// Over a vertical strip of columns, the ellipse's top boundary is concave in x and its
    /// bottom convex: their extremes over the strip are at the ellipse's topmost and
    /// bottommost points clamped into the strip (as in `tile_binning`'s bands, transposed).
    /// With Q the box's contour (half_x^2 = Q c / det), the boundary rows at offset dx are
    /// (-b dx +- sqrt(det (half_x^2 - dx^2))) / c.
    fn set_group_rows(
        &mut self,
        s: &BlendSplat,
        rect: &TileRect,
        fp: &PixelFootprint,
        col0: usize,
        groups: std::ops::Range<usize>,
        rows: std::ops::Range<usize>,
    ) {
        let [a, b, c] = s.conic;
        let (hx, hy) = (s.half[0], s.half[1]);
        // Per splat: one division and one square root; per group two square roots.
        let inv_c = 1.0 / c;
        let (slope, scale) = (-b * inv_c, (a * c - b * b).max(0.0).sqrt() * inv_c);
        let (hx2, dx_top) = (hx * hx * WIDEN, -hy * b / a);
        let boundary =
            |dx: f32, sign: f32| slope * dx + sign * scale * (hx2 - dx * dx).max(0.0).sqrt();
        for gi in groups {
            // Offsets of the group's footprint columns (pixel centres) from the centre.
            let first = rect.x0 as usize + col0 + gi * LANES;
            let x_lo = first.max(fp.x0 as usize) as f32 + 0.5;
            let x_hi = (first + LANES).min(fp.x1 as usize) as f32 - 0.5;
            let (d0, d1) = (x_lo - s.xy[0], x_hi - s.xy[0]);
            let top = boundary(dx_top.max(d0).min(d1), 1.0) + SPAN_WIDEN * hy;
            let bottom = boundary((-dx_top).max(d0).min(d1), -1.0) - SPAN_WIDEN * hy;
            self.group_rows[gi] = if top.is_finite() && bottom.is_finite() {
                let (y0, y1) = pixel_span(s.xy[1] + bottom, s.xy[1] + top, fp.y0, fp.y1);
                (y0 - rect.y0) as usize..(y1 - rect.y0) as usize
            } else {
                rows.clone()
            };
        }
    }
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

    /// Every pixel of the footprint box that a lane group's rows leave out would have been
    /// skipped by the kernels' own test (sigma < 0 or alpha < 1/255, computed exactly as
    /// they do), so leaving it out changes no bit. Splats from round to needle-thin (200:1),
    /// all opacities, centres in and around the tile.
    #[test]
    fn group_rows_drop_only_pixels_below_the_alpha_threshold() {
        use super::super::lanes::{exp_neg, sigma_at};
        use super::super::options::{ALPHA_MAX, ALPHA_MIN};
        let mut rng = crate::test_rng::Lcg::new(7);
        let rect = TileRect {
            x0: 32,
            y0: 16,
            x1: 64,
            y1: 48,
        };
        let mut geo = TileGeometry::new(32);
        geo.set_tile(&rect);
        let (mut dropped, mut wide) = (0usize, 0usize);
        for i in 0..20_000 {
            let long = 0.3 + 40.0 * rng.uniform().powi(2);
            let short = 0.3 + (long - 0.3) * rng.uniform().powi(if i % 2 == 0 { 1 } else { 6 });
            let th = std::f32::consts::PI * rng.uniform();
            let (cs, sn) = (th.cos(), th.sin());
            // Covariance R diag(long^2, short^2) R^T plus the 0.3 px blur.
            let (l2, s2) = (long * long, short * short);
            let cov = [
                cs * cs * l2 + sn * sn * s2 + 0.3,
                cs * sn * (l2 - s2),
                sn * sn * l2 + cs * cs * s2 + 0.3,
            ];
            let det = cov[0] * cov[2] - cov[1] * cov[1];
            let opacity = ALPHA_MIN + (1.0 - ALPHA_MIN) * rng.uniform();
            let qmax = 2.0 * (opacity / ALPHA_MIN).ln();
            let s = BlendSplat {
                xy: [
                    rect.x0 as f32 - 20.0 + 72.0 * rng.uniform(),
                    rect.y0 as f32 - 20.0 + 72.0 * rng.uniform(),
                ],
                conic: [cov[2] / det, -cov[1] / det, cov[0] / det],
                opacity,
                half: [(qmax * cov[0]).sqrt(), (qmax * cov[2]).sqrt()],
            };
            let box_fp = PixelFootprint::new(&s, &rect);
            let Some(fp) = geo.footprint(&s, &box_fp, &rect) else {
                continue;
            };
            wide += (fp.groups.len() > 1) as usize;
            let [a, b, c] = s.conic;
            for gi in fp.groups.clone() {
                let rows = geo.group_rows[gi].clone();
                for y in box_fp.y0..box_fp.y1 {
                    let ly = (y - rect.y0) as usize;
                    if rows.contains(&ly) {
                        continue;
                    }
                    let dy = s.xy[1] - (y as f32 + 0.5);
                    for lx in fp.col0 + gi * LANES..fp.col0 + (gi + 1) * LANES {
                        let x = geo.xs[lx];
                        if !(x > fp.xlo && x < fp.xhi) {
                            continue;
                        }
                        dropped += 1;
                        let sigma = sigma_at(a, s.xy[0] - x, c * dy * dy, b * dy);
                        let alpha = (s.opacity * exp_neg(-sigma)).min(ALPHA_MAX);
                        assert!(
                            !(sigma >= 0.0 && alpha >= ALPHA_MIN),
                            "splat {i}: pixel ({x}, {y}) dropped with alpha {alpha}"
                        );
                    }
                }
            }
        }
        // Not vacuous: many footprints span several groups and many pixels were dropped.
        assert!(wide > 2_000 && dropped > 50_000, "{wide} {dropped}");
    }
}
