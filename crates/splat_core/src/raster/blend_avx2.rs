//! The blending kernels, forward and backward, with AVX2 intrinsics: eight pixels per
//! instruction.
//!
//! Every operation mirrors `forward_blend::blend_tile_scalar`, `backward_blend::backward_tile_scalar`
//! and `lanes::exp_neg` one to one (same operands, same order, no fused multiply-add;
//! `max`/`min` with the constant second so NaN lanes take the constant like the scalar
//! comparisons), so this path and the scalar one produce the same bits (`kernel_tests`).
//! Lanes the scalar code skips are computed here and masked out (+-0 added to sums that
//! are never -0, state kept).
//! Unsafe code here: unaligned loads and stores of eight elements, bounds-checked by
//! slicing first or, in the forward kernel, once per splat for its whole footprint box
//! (`TilePointers`), and the calls into `#[target_feature]` functions after
//! `is_x86_feature_detected!("avx2")`. (The rasterizer's other unsafe code: the AVX
//! builds' calls in `project_avx2` and `project_backward_batch`, and `prefetch`.)
#![allow(unsafe_code)]

use std::arch::x86_64::*;

use super::lanes::{EXP_COEFFS, LANES};
use super::options::{ALPHA_MAX, ALPHA_MIN};
use super::tile_geometry::{LaneFootprint, TileGeometry};
use super::tile_walk::{
    for_each_splat, for_each_splat_back, BackOut, BackScratch, BackSplat, BackTile, EvalCount,
    SplatInTile, TileInput, TileScratch, ISECT_FIXED,
};

/// Blends one tile; the caller checked that the CPU has AVX2.
/// `COUNT` selects the instance that counts its work in `scratch.evals`.
pub(super) fn blend_tile<const COUNT: bool>(
    tile: &TileInput,
    ch: usize,
    scratch: &mut TileScratch,
) {
    debug_assert!(std::arch::is_x86_feature_detected!("avx2"));
    // SAFETY: `forward_blend::blend_tile` calls this only after detecting AVX2.
    unsafe { blend_tile_avx2::<COUNT>(tile, ch, scratch) }
}

#[inline(always)]
fn load(v: &[f32]) -> __m256 {
    let v = &v[..LANES];
    // SAFETY: `v` holds 8 floats (sliced above); loadu has no alignment requirement.
    unsafe { _mm256_loadu_ps(v.as_ptr()) }
}

#[inline(always)]
fn store(v: &mut [f32], x: __m256) {
    let v = &mut v[..LANES];
    // SAFETY: as in `load`.
    unsafe { _mm256_storeu_ps(v.as_mut_ptr(), x) }
}

#[inline(always)]
fn load_u32(v: &[u32]) -> __m256i {
    let v = &v[..LANES];
    // SAFETY: 8 u32 = 32 bytes; loadu has no alignment requirement.
    unsafe { _mm256_loadu_si256(v.as_ptr().cast()) }
}

/// One lane group of footprint columns: the mask of lanes inside the footprint, dx = x_splat
/// - x_pixel, and a dx^2 (the row-independent part of sigma, hoisted out of the rows).
#[inline(always)]
fn column_group(
    xs: &[f32],
    gi: usize,
    fp: &LaneFootprint,
    sx: f32,
    a: f32,
) -> (__m256, __m256, __m256) {
    let x = load(&xs[fp.col0 + gi * LANES..]);
    // SAFETY: only called from the `#[target_feature(enable = "avx2")]` kernels below.
    unsafe {
        let s = _mm256_set1_ps;
        let cols = _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GT_OQ>(x, s(fp.xlo)),
            _mm256_cmp_ps::<_CMP_LT_OQ>(x, s(fp.xhi)),
        );
        let dx = _mm256_sub_ps(s(sx), x);
        (cols, dx, _mm256_mul_ps(_mm256_mul_ps(s(a), dx), dx))
    }
}

/// `[e(0), .., e(R - 1)]` written as a loop over the rows (no closure, so the intrinsics
/// inline into the AVX2 kernel).
macro_rules! rows {
    ($n:expr, $r:ident => $e:expr) => {{
        let mut v = [Zero::zero(); $n];
        for $r in 0..$n {
            v[$r] = $e;
        }
        v
    }};
}

/// The initial value of `rows!`'s arrays.
trait Zero: Copy {
    fn zero() -> Self;
}

impl Zero for __m256 {
    #[inline(always)]
    fn zero() -> Self {
        // SAFETY: only used in the AVX2 kernels.
        unsafe { _mm256_setzero_ps() }
    }
}

macro_rules! impl_zero {
    ($($t:ty),*) => {$(impl Zero for $t {
        #[inline(always)]
        fn zero() -> Self {
            0 as $t
        }
    })*};
}
impl_zero!(usize, i32, f32);

/// `exp_neg` on `R` registers at once, operation by operation, so that the independent
/// chains of `R` rows sit side by side in the instruction stream (the forward kernel).
#[inline(always)]
fn exp_neg_rows<const R: usize>(x: [__m256; R]) -> [__m256; R] {
    // SAFETY (whole body): only called from the `#[target_feature(enable = "avx2")]` kernels.
    unsafe {
        let s = _mm256_set1_ps;
        let x = rows!(R, r => _mm256_max_ps(x[r], s(-87.0)));
        const ROUND: f32 = 12_582_912.0;
        let t = rows!(R, r => _mm256_add_ps(_mm256_mul_ps(x[r], s(std::f32::consts::LOG2_E)), s(ROUND)));
        let n = rows!(R, r => _mm256_sub_ps(t[r], s(ROUND)));
        let r1 = rows!(R, r => {
            _mm256_sub_ps(
                _mm256_sub_ps(x[r], _mm256_mul_ps(n[r], s(0.693_359_4))),
                _mm256_mul_ps(n[r], s(-2.121_944_4e-4)),
            )
        });
        let c = EXP_COEFFS.map(|v| s(v));
        let r2 = rows!(R, r => _mm256_mul_ps(r1[r], r1[r]));
        let r4 = rows!(R, r => _mm256_mul_ps(r2[r], r2[r]));
        let lin = |a: __m256, b: __m256, r: __m256| _mm256_add_ps(_mm256_mul_ps(a, r), b);
        let p = rows!(R, r => {
            _mm256_add_ps(
                _mm256_mul_ps(lin(c[0], c[1], r1[r]), r4[r]),
                _mm256_add_ps(
                    _mm256_mul_ps(lin(c[2], c[3], r1[r]), r2[r]),
                    lin(c[4], c[5], r1[r]),
                ),
            )
        });
        let y =
            rows!(R, r => _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(p[r], r2[r]), r1[r]), s(1.0)));
        let scale = rows!(R, r => {
            let n_int = _mm256_sub_epi32(
                _mm256_castps_si256(t[r]),
                _mm256_set1_epi32(ROUND.to_bits() as i32),
            );
            _mm256_castsi256_ps(_mm256_slli_epi32(_mm256_add_epi32(n_int, _mm256_set1_epi32(127)), 23))
        });
        rows!(R, r => _mm256_mul_ps(y[r], scale[r]))
    }
}

/// The forward's tile buffers as raw pointers, bounds checked once per splat
/// (`for_footprint`) instead of at every load and store: with a checked slice per access
/// the hot loop spent more instructions on index arithmetic and its branches than on the
/// blending itself, and the extra live registers spilled the lane state to the stack.
struct TilePointers {
    trans: *mut f32,
    last: *mut u32,
    feat: *mut f32,
    plane: usize,
}

impl TilePointers {
    fn new(sc: &mut TileScratch, ch: usize) -> Self {
        let plane = sc.geo.plane();
        assert!(sc.trans.len() == plane && sc.last.len() == plane && sc.feat.len() == plane * ch);
        Self {
            trans: sc.trans.as_mut_ptr(),
            last: sc.last.as_mut_ptr(),
            feat: sc.feat.as_mut_ptr(),
            plane,
        }
    }
}

/// What the forward kernel needs of one splat and one lane group of its footprint.
struct GroupLanes<'a> {
    sp: &'a SplatInTile<'a>,
    /// Offset of the group's first lane in row 0 of the tile buffers.
    col: usize,
    cols: __m256,
    dx: __m256,
    a_dx2: __m256,
}

/// Blends `R` rows of one lane group (distinct rows: independent pixels); subtracts the
/// stop masks of its lanes (-1 where a pixel stopped) from `stopped`.
///
/// # Safety
/// AVX2 is enabled, and `rows[r] * stride + g.col + LANES <= p.plane` for every row
/// (checked per splat by the caller), with `p` made from the scratch of `geo`.
#[inline(always)]
unsafe fn blend_rows<const R: usize, const COUNT: bool, const CH: usize>(
    g: &GroupLanes,
    rows: [usize; R],
    t_min: __m256,
    geo: &TileGeometry,
    p: &TilePointers,
    evals: &mut EvalCount,
    stopped: &mut __m256i,
) {
    let s = _mm256_set1_ps;
    let sp = g.sp;
    let [_, b, c] = sp.s.conic;
    let base: [usize; R] = rows!(R, r => rows[r] * geo.stride + g.col);
    let t: [__m256; R] = rows!(R, r => _mm256_loadu_ps(p.trans.add(base[r])));
    // All ones where the pixel stopped (T's sign bit set: `TileScratch::trans`).
    let stopped_before: [__m256; R] = rows!(R, r => {
        _mm256_castsi256_ps(_mm256_srai_epi32::<31>(_mm256_castps_si256(t[r])))
    });
    let inside: [__m256; R] = rows!(R, r => _mm256_andnot_ps(stopped_before[r], g.cols));
    let any: [i32; R] = rows!(R, r => _mm256_movemask_ps(inside[r]));
    // Pixels that already stopped cost nothing more.
    if any.iter().all(|&m| m == 0) {
        return;
    }
    if COUNT {
        evals.groups += any.iter().filter(|&&m| m != 0).count() as u64;
    }
    // sigma_at: 0.5 * (a dx dx + c dy^2) + dx * b dy
    let dy: [f32; R] = rows!(R, r => sp.s.xy[1] - *geo.ys.get_unchecked(rows[r]));
    let sigma: [__m256; R] = rows!(R, r => {
        _mm256_add_ps(
            _mm256_mul_ps(s(0.5), _mm256_add_ps(g.a_dx2, s(c * dy[r] * dy[r]))),
            _mm256_mul_ps(g.dx, s(b * dy[r])),
        )
    });
    let e = exp_neg_rows::<R>(rows!(R, r => _mm256_xor_ps(sigma[r], s(-0.0))));
    let opacity = s(sp.s.opacity);
    let alpha: [__m256; R] =
        rows!(R, r => _mm256_min_ps(_mm256_mul_ps(opacity, e[r]), s(ALPHA_MAX)));
    let ok: [__m256; R] = rows!(R, r => {
        _mm256_and_ps(
            _mm256_and_ps(inside[r], _mm256_cmp_ps::<_CMP_GE_OQ>(sigma[r], s(0.0))),
            _mm256_cmp_ps::<_CMP_GE_OQ>(alpha[r], s(ALPHA_MIN)),
        )
    });
    let next_t: [__m256; R] = rows!(R, r => _mm256_mul_ps(t[r], _mm256_sub_ps(s(1.0), alpha[r])));
    let stop: [__m256; R] = rows!(R, r => {
        _mm256_and_ps(ok[r], _mm256_cmp_ps::<_CMP_LE_OQ>(next_t[r], t_min))
    });
    let add: [__m256; R] = rows!(R, r => _mm256_andnot_ps(stop[r], ok[r]));
    if COUNT {
        for a in add {
            evals.blended += (_mm256_movemask_ps(a) as u32).count_ones() as u64;
        }
    }
    let weight: [__m256; R] = rows!(R, r => _mm256_and_ps(add[r], _mm256_mul_ps(alpha[r], t[r])));
    // CH = 0: the channel count known only at run time.
    let ch = if CH > 0 { CH } else { sp.f.len() };
    for ci in 0..ch {
        let fc = s(*sp.f.get_unchecked(ci));
        for r in 0..R {
            let o = p.feat.add(ci * p.plane + base[r]);
            _mm256_storeu_ps(
                o,
                _mm256_add_ps(_mm256_loadu_ps(o), _mm256_mul_ps(weight[r], fc)),
            );
        }
    }
    let k1 = _mm256_set1_epi32(sp.k1 as i32);
    for r in 0..R {
        // T where nothing was added, next T where the splat was, its sign set where the
        // pixel stopped.
        let kept_t = _mm256_blendv_ps(t[r], next_t[r], add[r]);
        let sign = _mm256_and_ps(stop[r], s(-0.0));
        _mm256_storeu_ps(p.trans.add(base[r]), _mm256_or_ps(kept_t, sign));
        // last = k1 where added: k1 exceeds every earlier value, so an unsigned max
        // with k1 & add sets exactly those lanes. A blend of the loaded value would
        // compile to a masked store (vmaskmovps), microcoded and slow on AMD cores.
        let last = p.last.add(base[r]).cast::<__m256i>();
        let k1_add = _mm256_and_si256(k1, _mm256_castps_si256(add[r]));
        _mm256_storeu_si256(last, _mm256_max_epu32(_mm256_loadu_si256(last), k1_add));
        // A vector count instead of a population count per row (popcnt is not part of
        // the AVX2 target feature; its software fallback is five instructions).
        *stopped = _mm256_sub_epi32(*stopped, _mm256_castps_si256(stop[r]));
    }
}

/// The forward kernel's instance for `ch` channels: the common counts get their own, so
/// that the channel loop unrolls.
#[target_feature(enable = "avx2")]
fn blend_tile_avx2<const COUNT: bool>(tile: &TileInput, ch: usize, scratch: &mut TileScratch) {
    match ch {
        3 => blend_channels::<COUNT, 3>(tile, ch, scratch),
        4 => blend_channels::<COUNT, 4>(tile, ch, scratch),
        1 => blend_channels::<COUNT, 1>(tile, ch, scratch),
        _ => blend_channels::<COUNT, 0>(tile, ch, scratch),
    }
}

#[target_feature(enable = "avx2")]
fn blend_channels<const COUNT: bool, const CH: usize>(
    tile: &TileInput,
    ch: usize,
    scratch: &mut TileScratch,
) {
    let t_min = _mm256_set1_ps(tile.t_min);
    // Each splat's features are `ch` values (`for_each_splat`), read unchecked below.
    assert!(CH == 0 || CH == ch);
    for_each_splat(tile, ch, scratch, |sp: &SplatInTile, sc| {
        let fp = &sp.fp;
        let p = TilePointers::new(sc, ch);
        // Every access below is at row * stride + col0 + group * LANES + lane, lane <
        // LANES: in bounds if the last group of the last row is (the footprint has at
        // least one row and one group).
        let (stride, groups) = (sc.geo.stride, fp.groups.end);
        assert!(
            fp.rows.end <= sc.geo.ys.len()
                && (fp.rows.end - 1) * stride + fp.col0 + groups * LANES <= p.plane
                && fp.col0 + groups * LANES <= sc.geo.xs.len()
        );
        let mut stopped = _mm256_setzero_si256();
        for gi in fp.groups.clone() {
            let (cols, dx, a_dx2) = column_group(&sc.geo.xs, gi, fp, sp.s.xy[0], sp.s.conic[0]);
            let g = GroupLanes {
                sp,
                col: fp.col0 + gi * LANES,
                cols,
                dx,
                a_dx2,
            };
            // Two rows per step: their long exp chains overlap.
            let mut ly = fp.rows.start;
            // SAFETY: AVX2 is enabled here; the rows and groups are in bounds (asserted
            // above) of the buffers `p` points into, which nothing else touches meanwhile.
            unsafe {
                while ly + 2 <= fp.rows.end {
                    blend_rows::<2, COUNT, CH>(
                        &g,
                        [ly, ly + 1],
                        t_min,
                        &sc.geo,
                        &p,
                        &mut sc.evals,
                        &mut stopped,
                    );
                    ly += 2;
                }
                if ly < fp.rows.end {
                    blend_rows::<1, COUNT, CH>(
                        &g,
                        [ly],
                        t_min,
                        &sc.geo,
                        &p,
                        &mut sc.evals,
                        &mut stopped,
                    );
                }
            }
        }
        let mut counts = [0u32; LANES];
        // SAFETY: 8 u32 = 32 bytes; storeu has no alignment requirement.
        unsafe { _mm256_storeu_si256(counts.as_mut_ptr().cast(), stopped) };
        counts.iter().sum()
    });
}

/// Feature channels the AVX2 backward keeps in registers; wider features use the scalar
/// kernel.
pub(super) const MAX_BACKWARD_CHANNELS: usize = 4;

/// Backward of one tile into `out` (rows +0 on entry: the rows of splats no pixel
/// differentiated are not put); the caller checked AVX2 and
/// `ch <= MAX_BACKWARD_CHANNELS`.
/// `COUNT` selects the instance that counts its work in `scratch.evals`.
pub(super) fn backward_tile<const COUNT: bool>(
    tile: &BackTile,
    ch: usize,
    scratch: &mut BackScratch,
    out: &mut BackOut,
) {
    debug_assert!(ch <= MAX_BACKWARD_CHANNELS && std::arch::is_x86_feature_detected!("avx2"));
    // One instance per channel count: with the count known, the per-channel loops unroll
    // and their sums stay in registers instead of arrays indexed at run time.
    // SAFETY: `backward_blend::backward_tile` calls this only after detecting AVX2.
    unsafe {
        match ch {
            3 => backward_tile_avx2::<COUNT, 3>(tile, scratch, out),
            4 => backward_tile_avx2::<COUNT, 4>(tile, scratch, out),
            1 => backward_tile_avx2::<COUNT, 1>(tile, scratch, out),
            2 => backward_tile_avx2::<COUNT, 2>(tile, scratch, out),
            _ => backward_tile_avx2::<COUNT, 0>(tile, scratch, out),
        }
    }
}

/// `lanes::lane_sum` of eight registers at once, in its tree: (l0+l4 + l2+l6) + (l1+l5 +
/// l3+l7), each addition with the same operands in the same order, eight sums per
/// instruction after a transposition (21 instructions instead of 8 x 7).
#[inline(always)]
fn lane_sums(v: &[__m256; 8]) -> [f32; 8] {
    // SAFETY (whole body): only called from `backward_tile_avx2`, which has AVX2 enabled.
    unsafe {
        // [a0+a4, a1+a5, a2+a6, a3+a7 | b0+b4, b1+b5, b2+b6, b3+b7] for registers a, b.
        let halves = |a: __m256, b: __m256| {
            _mm256_add_ps(
                _mm256_permute2f128_ps::<0x20>(a, b),
                _mm256_permute2f128_ps::<0x31>(a, b),
            )
        };
        let (p01, p23) = (halves(v[0], v[1]), halves(v[2], v[3]));
        let (p45, p67) = (halves(v[4], v[5]), halves(v[6], v[7]));
        // With s = the four sums above per register: [s0+s2, s1+s3] of a, c | of b, d.
        let pairs = |p: __m256, q: __m256| {
            let (p, q) = (_mm256_castps_pd(p), _mm256_castps_pd(q));
            _mm256_add_ps(
                _mm256_castpd_ps(_mm256_unpacklo_pd(p, q)),
                _mm256_castpd_ps(_mm256_unpackhi_pd(p, q)),
            )
        };
        let (u0, u1) = (pairs(p01, p23), pairs(p45, p67));
        // (s0+s2) + (s1+s3): registers 0, 2, 4, 6 | 1, 3, 5, 7.
        let r = _mm256_add_ps(
            _mm256_shuffle_ps::<0b10_00_10_00>(u0, u1),
            _mm256_shuffle_ps::<0b11_01_11_01>(u0, u1),
        );
        let mut out = [0.0f32; 8];
        store(&mut out, r);
        [
            out[0], out[4], out[1], out[5], out[2], out[6], out[3], out[7],
        ]
    }
}

/// What the backward kernel needs of one splat and one lane group of its footprint.
struct BackGroup<const CH: usize> {
    conic: [f32; 3],
    opacity: __m256,
    /// The splat's position in the tile list (pixels with `last > k` saw it).
    k: __m256i,
    fc: [__m256; CH],
    cols: __m256,
    dx: __m256,
    a_dx2: __m256,
    /// Offset of the group's first lane in row 0 of the tile buffers.
    col: usize,
}

/// The backward kernel's per-splat sums.
struct BackSums<const CH: usize> {
    /// Lane sums of v_x, v_y, v_a, v_b, v_c, v_opacity, and of the features.
    acc: [__m256; ISECT_FIXED],
    acc_f: [__m256; CH],
    /// Whether any pixel differentiated this splat; if none, its sums stay +0 as `out`
    /// came (a splat hidden in this tile: the lane sums would give +0 too).
    touched: bool,
}

/// The backward of `R` rows of one lane group (distinct rows: independent pixels), the
/// rows' terms added to the sums in row order. A row none of whose pixels saw the splat,
/// or with no pixel that blended it, is computed alongside a row that has one when they
/// share a step: its lanes are all outside `m`, where every stored value keeps its bits
/// and every term is +-0 (see below), so the result is that of skipping it.
#[inline(always)]
fn back_rows<const R: usize, const COUNT: bool, const CH: usize>(
    g: &BackGroup<CH>,
    rows: [usize; R],
    sc: &mut BackScratch,
    sums: &mut BackSums<CH>,
) {
    // SAFETY (whole body): only called from `backward_tile_avx2`, which has AVX2 enabled.
    unsafe {
        let s = _mm256_set1_ps;
        let zero = _mm256_setzero_ps();
        let (plane, stride) = (sc.geo.plane(), sc.geo.stride);
        let [ca, cb, cc] = g.conic;
        let base: [usize; R] = rows!(R, r => rows[r] * stride + g.col);
        // Pixels whose last contributor is in front of this splat never saw it.
        let active: [__m256; R] = rows!(R, r => {
            let seen = _mm256_cmpgt_epi32(load_u32(&sc.last[base[r]..]), g.k);
            _mm256_and_ps(g.cols, _mm256_castsi256_ps(seen))
        });
        let any: [i32; R] = rows!(R, r => _mm256_movemask_ps(active[r]));
        if any.iter().all(|&m| m == 0) {
            return;
        }
        if COUNT {
            sc.evals.groups += any.iter().filter(|&&m| m != 0).count() as u64;
        }
        let dy: [__m256; R] = rows!(R, r => s(sc.geo.row_dy[rows[r]]));
        let sigma: [__m256; R] = rows!(R, r => {
            _mm256_add_ps(
                _mm256_mul_ps(s(0.5), _mm256_add_ps(g.a_dx2, s(sc.geo.row_c[rows[r]]))),
                _mm256_mul_ps(g.dx, s(sc.geo.row_b[rows[r]])),
            )
        });
        let vis = exp_neg_rows::<R>(rows!(R, r => _mm256_xor_ps(sigma[r], s(-0.0))));
        let raw: [__m256; R] = rows!(R, r => _mm256_mul_ps(g.opacity, vis[r]));
        let alpha: [__m256; R] = rows!(R, r => _mm256_min_ps(raw[r], s(ALPHA_MAX)));
        let m: [__m256; R] = rows!(R, r => {
            _mm256_and_ps(
                _mm256_and_ps(active[r], _mm256_cmp_ps::<_CMP_GE_OQ>(sigma[r], zero)),
                _mm256_cmp_ps::<_CMP_GE_OQ>(alpha[r], s(ALPHA_MIN)),
            )
        });
        let blended: [i32; R] = rows!(R, r => _mm256_movemask_ps(m[r]));
        if COUNT {
            sc.evals.blended += blended
                .iter()
                .map(|&b| (b as u32).count_ones() as u64)
                .sum::<u64>();
        }
        if blended.iter().all(|&b| b == 0) {
            return;
        }
        sums.touched = true;
        // 1 in the lanes outside m, so that t_k is T unchanged there and the stores below
        // need no blend of the loaded values (which would compile to masked stores,
        // vmaskmovps, microcoded and slow on AMD cores). Those lanes' other values are
        // masked out.
        let ra: [__m256; R] = rows!(R, r => {
            _mm256_blendv_ps(
                s(1.0),
                _mm256_div_ps(s(1.0), _mm256_max_ps(_mm256_sub_ps(s(1.0), alpha[r]), s(1e-6))),
                m[r],
            )
        });
        let t_k: [__m256; R] = rows!(R, r => _mm256_mul_ps(load(&sc.trans[base[r]..]), ra[r]));
        let fac: [__m256; R] = rows!(R, r => _mm256_mul_ps(alpha[r], t_k[r]));
        // fac is finite in every lane (alpha <= 0.99, t_k is T outside m), and so are the
        // features: fc fac_m is +-0 outside m.
        let fac_m: [__m256; R] = rows!(R, r => _mm256_and_ps(m[r], fac[r]));
        let mut v_al: [__m256; R] = rows!(R, r => _mm256_mul_ps(load(&sc.va_tf[base[r]..]), ra[r]));
        for c in 0..CH {
            for r in 0..R {
                let vo = load(&sc.v_out[c * plane + base[r]..]);
                let b = &mut sc.buf[c * plane + base[r]..];
                let bv = load(b);
                sums.acc_f[c] = _mm256_add_ps(
                    sums.acc_f[c],
                    _mm256_and_ps(m[r], _mm256_mul_ps(fac[r], vo)),
                );
                v_al[r] = _mm256_add_ps(
                    v_al[r],
                    _mm256_mul_ps(
                        _mm256_sub_ps(_mm256_mul_ps(g.fc[c], t_k[r]), _mm256_mul_ps(bv, ra[r])),
                        vo,
                    ),
                );
                // +-0 outside m keeps buf's bits: buf starts at +0 and a sum is -0 only if
                // both terms are, so buf is never -0. (The sums of v_out products keep
                // their own mask: v_out is the caller's and may hold Inf.)
                store(b, _mm256_add_ps(bv, _mm256_mul_ps(g.fc[c], fac_m[r])));
            }
        }
        for r in 0..R {
            store(&mut sc.trans[base[r]..], t_k[r]);
            // Where alpha was clamped it depends on neither opacity nor position.
            let gate = _mm256_and_ps(m[r], _mm256_cmp_ps::<_CMP_LE_OQ>(raw[r], s(ALPHA_MAX)));
            // Masked once here: every term below is v_al times finite values (the splat's
            // conic and offsets, raw, vis), so +-0 outside the gate, which adds nothing to
            // the sums (never -0, as buf).
            let v_al = _mm256_and_ps(gate, v_al[r]);
            let v_sigma = _mm256_mul_ps(_mm256_xor_ps(raw[r], s(-0.0)), v_al);
            let half_vs = _mm256_mul_ps(s(0.5), v_sigma);
            let (dx, dy) = (g.dx, dy[r]);
            let terms = [
                _mm256_mul_ps(
                    v_sigma,
                    _mm256_add_ps(_mm256_mul_ps(s(ca), dx), _mm256_mul_ps(s(cb), dy)),
                ),
                _mm256_mul_ps(
                    v_sigma,
                    _mm256_add_ps(_mm256_mul_ps(s(cb), dx), _mm256_mul_ps(s(cc), dy)),
                ),
                _mm256_mul_ps(_mm256_mul_ps(half_vs, dx), dx),
                _mm256_mul_ps(_mm256_mul_ps(v_sigma, dx), dy),
                _mm256_mul_ps(_mm256_mul_ps(half_vs, dy), dy),
                _mm256_mul_ps(vis[r], v_al),
            ];
            for (a, t) in sums.acc.iter_mut().zip(terms) {
                *a = _mm256_add_ps(*a, t);
            }
        }
    }
}

#[target_feature(enable = "avx2")]
fn backward_tile_avx2<const COUNT: bool, const CH: usize>(
    tile: &BackTile,
    scratch: &mut BackScratch,
    out: &mut BackOut,
) {
    let ch = CH;
    let s = _mm256_set1_ps;
    let zero = _mm256_setzero_ps();
    for_each_splat_back(tile, ch, scratch, out, |sp: &BackSplat, sc, o| {
        let [ca, cb, cc] = sp.s.conic;
        let (opacity, k) = (s(sp.s.opacity), _mm256_set1_epi32(sp.k as i32));
        let mut fc = [zero; CH];
        for (c, v) in sp.f.iter().enumerate().take(CH) {
            fc[c] = s(*v);
        }
        let mut sums = BackSums {
            acc: [zero; ISECT_FIXED],
            acc_f: [zero; CH],
            touched: false,
        };
        for gi in sp.fp.groups.clone() {
            let (cols, dx, a_dx2) = column_group(&sc.geo.xs, gi, &sp.fp, sp.s.xy[0], ca);
            let group = BackGroup {
                conic: [ca, cb, cc],
                opacity,
                k,
                fc,
                cols,
                dx,
                a_dx2,
                col: sp.fp.col0 + gi * LANES,
            };
            // Two rows per step, as in the forward: their long chains overlap.
            let rows = sc.geo.group_rows[gi].clone();
            let mut ly = rows.start;
            while ly + 2 <= rows.end {
                back_rows::<2, COUNT, CH>(&group, [ly, ly + 1], sc, &mut sums);
                ly += 2;
            }
            if ly < rows.end {
                back_rows::<1, COUNT, CH>(&group, [ly], sc, &mut sums);
            }
        }
        let BackSums {
            acc,
            acc_f,
            touched,
        } = sums;
        if touched {
            // The sums in groups of eight registers (zeros past the last, not stored).
            let mut regs = [zero; 16];
            regs[..ISECT_FIXED].copy_from_slice(&acc);
            regs[ISECT_FIXED..ISECT_FIXED + CH].copy_from_slice(&acc_f);
            for (o, r) in o.chunks_mut(LANES).zip(regs.chunks_exact(LANES)) {
                let sums = lane_sums(r.try_into().unwrap());
                o.copy_from_slice(&sums[..o.len()]);
            }
        }
        touched
    });
}
