//! The AVX2 and scalar blending kernels, forward and backward, give the same bits.

use super::backward_blend::backward_tile_scalar;
use super::blend_avx2;
use super::forward_blend::blend_tile_scalar;
use super::options::ALPHA_MIN;
use super::tile_geometry::{pixel_boxes, BlendSplat, PixelFootprint, TileRect};
use super::tile_walk::{BackOut, BackScratch, BackTile, TileInput, TileScratch, ISECT_FIXED};
use crate::test_rng::Lcg;

/// The footprint boxes the blending loops read, as `forward_blend` and `backward_blend`
/// compute them.
fn boxes(splats: &[BlendSplat], rect: &TileRect) -> Vec<PixelFootprint> {
    let mut out = Vec::new();
    pixel_boxes(splats, rect, &mut out);
    out
}

/// A random tile list with `ch` feature channels: overlapping anisotropic splats, some
/// fully opaque.
fn random_tile(n: usize, ch: usize, rng: &mut Lcg, rect: TileRect) -> (Vec<BlendSplat>, Vec<f32>) {
    let (w, h) = ((rect.x1 - rect.x0) as f32, (rect.y1 - rect.y0) as f32);
    let mut splats = Vec::new();
    let mut feats = Vec::new();
    for i in 0..n {
        let (s1, s2, th) = (
            0.3 + 6.0 * rng.uniform(),
            0.3 + 3.0 * rng.uniform(),
            3.2 * rng.uniform(),
        );
        let (c, s) = (th.cos(), th.sin());
        let (ia, ib) = (1.0 / (s1 * s1), 1.0 / (s2 * s2));
        let opacity = if i % 7 == 0 {
            1.0
        } else {
            0.01 + 0.99 * rng.uniform()
        };
        let conic = [
            c * c * ia + s * s * ib,
            c * s * (ia - ib),
            s * s * ia + c * c * ib,
        ];
        let qmax = 2.0 * (opacity / ALPHA_MIN).ln();
        let det = conic[0] * conic[2] - conic[1] * conic[1];
        splats.push(BlendSplat {
            xy: [
                rect.x0 as f32 - 4.0 + (w + 8.0) * rng.uniform(),
                rect.y0 as f32 - 4.0 + (h + 8.0) * rng.uniform(),
            ],
            conic,
            opacity,
            half: [
                (qmax * conic[2] / det).sqrt(),
                (qmax * conic[0] / det).sqrt(),
            ],
        });
        for c in 0..ch {
            let u = rng.uniform();
            feats.push([u, u - 0.5, 4.0 * u][c % 3]);
        }
    }
    (splats, feats)
}

/// Tile sizes and rectangles: full tiles, tiles cut by the image border, sizes that are
/// not a multiple of the lane count.
const RECTS: [(usize, TileRect); 5] = [
    (
        16,
        TileRect {
            x0: 32,
            y0: 16,
            x1: 48,
            y1: 32,
        },
    ),
    (
        16,
        TileRect {
            x0: 32,
            y0: 16,
            x1: 45,
            y1: 21,
        },
    ),
    (
        8,
        TileRect {
            x0: 8,
            y0: 0,
            x1: 16,
            y1: 8,
        },
    ),
    (
        13,
        TileRect {
            x0: 13,
            y0: 13,
            x1: 26,
            y1: 26,
        },
    ),
    (
        32,
        TileRect {
            x0: 0,
            y0: 32,
            x1: 32,
            y1: 64,
        },
    ),
];

/// (seed, splats, t_min): few and many splats, early stops, no early stop.
const CASES: [(u64, usize, f32); 4] = [(1, 40, 1e-4), (2, 400, 1e-4), (3, 200, 0.3), (4, 5, 0.0)];

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn forward_scratch(tile: &TileInput, ts: usize, ch: usize, avx: bool) -> TileScratch {
    let mut sc = TileScratch::new(ts, ch);
    sc.reset(&tile.rect);
    if avx {
        blend_avx2::blend_tile::<true>(tile, ch, &mut sc);
    } else {
        blend_tile_scalar::<true>(tile, ch, &mut sc);
    }
    sc
}

/// Channel counts of the forward kernel's own instances (1, 3, 4) and of its run-time
/// channel loop (2, 6).
const FORWARD_CHANNELS: [usize; 5] = [3, 1, 2, 4, 6];

#[test]
fn forward_kernels_agree() {
    if !std::arch::is_x86_feature_detected!("avx2") {
        return;
    }
    for (ts, rect) in RECTS {
        for ((seed, n, t_min), ch) in CASES
            .into_iter()
            .flat_map(|c| FORWARD_CHANNELS.map(|ch| (c, ch)))
        {
            let (splats, feats) = random_tile(n, ch, &mut Lcg::new(seed), rect);
            let boxes = boxes(&splats, &rect);
            let tile = TileInput {
                splats: &splats,
                boxes: &boxes,
                features: &feats,
                rect,
                t_min,
                simd: true,
            };
            let (a, b) = (
                forward_scratch(&tile, ts, ch, true),
                forward_scratch(&tile, ts, ch, false),
            );
            assert_eq!(
                bits(&a.trans),
                bits(&b.trans),
                "ts {ts} seed {seed} ch {ch}"
            );
            assert_eq!(bits(&a.feat), bits(&b.feat), "ts {ts} seed {seed} ch {ch}");
            assert_eq!(a.last, b.last);
            assert_eq!(a.active, b.active);
            // Both skip the same lane groups, and the counts add up.
            assert_eq!(a.evals, b.evals, "ts {ts} seed {seed}");
            assert!(b.evals.blended > 0 && b.evals.blended <= 8 * b.evals.groups);
            // Not trivial: something blended, and with many splats some pixels stopped.
            assert!(b.last.iter().any(|&l| l > 0));
            if n >= 200 {
                assert!(b.active < ((rect.x1 - rect.x0) * (rect.y1 - rect.y0)) as usize);
            }
        }
    }
}

#[test]
fn backward_kernels_agree() {
    if !std::arch::is_x86_feature_detected!("avx2") {
        return;
    }
    for (ts, rect) in RECTS {
        for (seed, n, t_min) in CASES {
            let mut rng = Lcg::new(seed);
            let (splats, feats) = random_tile(n, 3, &mut rng, rect);
            let boxes = boxes(&splats, &rect);
            let tile = TileInput {
                splats: &splats,
                boxes: &boxes,
                features: &feats,
                rect,
                t_min,
                simd: true,
            };
            let fw = forward_scratch(&tile, ts, 3, false);
            let (mut t_final, mut last) = (vec![1.0; ts * ts], vec![0; ts * ts]);
            fw.write_state(&rect, &mut t_final, &mut last);
            // Every channel count the AVX2 kernel has an instance for: the tile's
            // features cut to `ch` channels or widened by a fourth.
            for ch in 1..=blend_avx2::MAX_BACKWARD_CHANNELS {
                let feats: Vec<f32> = feats
                    .chunks_exact(3)
                    .flat_map(|f| (0..ch).map(move |c| if c < 3 { f[c] } else { 0.5 * f[0] }))
                    .collect();
                // Upstream gradients on an image just large enough for the tile.
                let (w, h) = (rect.x1 as usize, rect.y1 as usize);
                let v_render: Vec<f32> = (0..w * h * ch).map(|_| rng.uniform() - 0.5).collect();
                let v_alpha: Vec<f32> = (0..w * h).map(|_| rng.uniform() - 0.5).collect();
                let back = BackTile {
                    splats: &splats,
                    boxes: &boxes,
                    features: &feats,
                    rect,
                    simd: true,
                };
                let run = |avx: bool| {
                    let mut sc = BackScratch::new(ts, ch);
                    sc.reset(&rect, ch, w, &t_final, &last, &v_render, &v_alpha);
                    let mut out = vec![0.0f32; n * (ISECT_FIXED + ch)];
                    if avx {
                        blend_avx2::backward_tile::<true>(
                            &back,
                            ch,
                            &mut sc,
                            &mut BackOut::Rows(&mut out),
                        );
                    } else {
                        backward_tile_scalar::<true>(
                            &back,
                            ch,
                            &mut sc,
                            &mut BackOut::Rows(&mut out),
                        );
                    }
                    (out, sc)
                };
                let ((ga, sa), (gb, sb)) = (run(true), run(false));
                assert_eq!(bits(&ga), bits(&gb), "ts {ts} seed {seed} ch {ch}");
                assert_eq!(bits(&sa.trans), bits(&sb.trans));
                assert_eq!(bits(&sa.buf), bits(&sb.buf));
                assert_eq!(sa.evals, sb.evals, "ts {ts} seed {seed}");
                // The backward differentiates exactly the pairs the forward blended.
                assert_eq!(sb.evals.blended, fw.evals.blended, "ts {ts} seed {seed}");
                assert!(gb.iter().any(|&g| g != 0.0));
            }
        }
    }
}
