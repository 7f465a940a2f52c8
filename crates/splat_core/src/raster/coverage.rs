//! Each group's silhouette in one camera of a forward pass (a plant's leaves, for their
//! occlusion): the pixels where the group's Gaussians, rendered alone, accumulate an alpha
//! of at least a threshold, and how many of them a label map gives the group.
//!
//! The same pixels as thresholding `forward`'s alpha of each group's Gaussians on their
//! own (tested, bit for bit), for much less work than a render per group:
//! - the forward pass's own projection and depth order serve every group: a splat's
//!   projection is its own, and a group's depth order is its members' places in the whole
//!   order (the sort is stable by (depth, index));
//! - each group's tile lists hold its members only (`tile_binning::bin`);
//! - the blend is the forward's own kernel with one constant channel, stopping a pixel as
//!   soon as it is in: accumulated alpha only grows, so a pixel is in once its
//!   transmittance reaches `T_stop`, the largest T whose alpha `1 - T` (f32) reaches the
//!   threshold. That is the kernel's stop rule with `t_min = T_stop`, which flags the
//!   pixel. The render's own `t_min` never stops a pixel first: one splat multiplies T by
//!   at least `1 - ALPHA_MAX`, so a pixel above `T_stop` cannot fall to `t_min` in one
//!   step while `t_min <= (1 - ALPHA_MAX) T_stop / 2` (checked);
//! - no image is written: each (group, tile) counts its flagged pixels.

use rayon::prelude::*;

use super::forward_blend::blend_list;
use super::forward_pass::ForwardState;
use super::options::{RasterOptions, ALPHA_MAX};
use super::tile_binning::{self, TileBins};
use super::tile_geometry::{TileList, TileRect};
use super::tile_walk::{kept_scratch, TileScratch};
use crate::{CoreError, CoreResult};

/// Pixels per group: `alone`, those of its silhouette; `visible`, those of them the
/// label map gives the group.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Coverage {
    pub alone: Vec<u64>,
    pub visible: Vec<u64>,
}

/// Labels of one view and what each group is called in them.
#[derive(Debug, Clone, Copy)]
pub struct LabelMap<'a> {
    /// [H, W] row-major: each pixel's label.
    pub labels: &'a [i32],
    /// [groups]: group g's pixels are those labelled `group_labels[g]`.
    pub group_labels: &'a [i32],
}

/// Each group's silhouette (`alpha >= alpha_threshold`) in camera `camera` of the forward
/// pass `state`, counted against `map`, the groups' tile lists `tile_size` pixels wide (any
/// size gives the same counts). `groups` [N] gives each Gaussian of the pass its group,
/// `0..map.group_labels.len()`, or -1: none.
pub fn group_coverage(
    state: &ForwardState,
    camera: usize,
    groups: &[i32],
    tile_size: u32,
    alpha_threshold: f32,
    map: LabelMap,
) -> CoreResult<Coverage> {
    let opts = RasterOptions {
        tile_size,
        ..state.opts
    };
    opts.validate()?;
    let t_stop = stop_transmittance(alpha_threshold)?;
    if opts.t_min > (1.0 - ALPHA_MAX) * t_stop / 2.0 {
        return Err(CoreError::input(format!(
            "the render's t_min {} is too large for the alpha threshold {alpha_threshold} (at \
             most {})",
            opts.t_min,
            (1.0 - ALPHA_MAX) * t_stop / 2.0
        )));
    }
    let Some(cam) = state.per_camera.get(camera) else {
        return Err(CoreError::input(format!(
            "camera {camera} of a pass of {} cameras",
            state.per_camera.len()
        )));
    };
    let (width, height) = (state.width, state.height);
    let count = map.group_labels.len();
    check_inputs(state.scene.n, groups, count, map.labels, width, height)?;
    let splats = &cam.splats;
    let ones = vec![1.0f32; splats.len()];
    let bins: Vec<TileBins> = group_orders(&cam.bins.depth_order, groups, count)
        .into_par_iter()
        .map(|order| tile_binning::bin(splats, order, width, height, tile_size, opts.tile_ellipse))
        .collect::<CoreResult<_>>()?;
    // Every (group, tile) with a list is one unit of work; the counts are integers, so
    // their sums do not depend on how the units are spread over threads.
    let units: Vec<(usize, usize)> = bins
        .iter()
        .enumerate()
        .flat_map(|(g, b)| {
            (0..b.n_tiles())
                .filter(|&t| !b.tile_range(t).is_empty())
                .map(move |t| (g, t))
        })
        .collect();
    let ts = tile_size as usize;
    let counted: Vec<(u64, u64)> = units
        .par_iter()
        .with_max_len(4)
        .map(|&(g, t)| {
            SCRATCH.with_borrow_mut(|kept| {
                let (scratch, list) =
                    kept_scratch(kept, |sc| sc.fits(ts, 1), || TileScratch::new(ts, 1));
                let b = &bins[g];
                list.gather(&b.isect_gid[b.tile_range(t)], splats, &ones, 1);
                let rect = TileRect::new(t, b, width, height);
                blend_list(list, rect, 1, (t_stop, opts.simd), scratch, false);
                count_flagged(scratch, &rect, width, map.labels, map.group_labels[g])
            })
        })
        .collect();
    let mut out = Coverage {
        alone: vec![0; count],
        visible: vec![0; count],
    };
    for (&(g, _), (alone, visible)) in units.iter().zip(counted) {
        out.alone[g] += alone;
        out.visible[g] += visible;
    }
    Ok(out)
}

thread_local! {
    /// Each thread's tile scratch, kept between tiles and calls (as the forward's).
    static SCRATCH: std::cell::RefCell<Option<(TileScratch, TileList)>> =
        const { std::cell::RefCell::new(None) };
}

/// The largest transmittance T in [0, 1] whose alpha `1 - T` (f32) is at least
/// `threshold`: `1 - T` only falls as T grows, so the T that pass are [0, T_stop]. Found
/// by bisection on the bit patterns (non-negative floats order as their bits).
fn stop_transmittance(threshold: f32) -> CoreResult<f32> {
    if !(threshold > 0.0 && threshold <= 1.0) {
        return Err(CoreError::input(format!(
            "the alpha threshold must be in (0, 1], got {threshold}"
        )));
    }
    let passes = |bits: u32| 1.0 - f32::from_bits(bits) >= threshold;
    // passes(0) (alpha 1) holds, passes(1.0) (alpha 0) does not.
    let (mut lo, mut hi) = (0u32, 1.0f32.to_bits());
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if passes(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok(f32::from_bits(lo))
}

fn check_inputs(
    n: usize,
    groups: &[i32],
    count: usize,
    labels: &[i32],
    width: u32,
    height: u32,
) -> CoreResult<()> {
    if groups.len() != n {
        return Err(CoreError::input(format!(
            "groups has {} entries for {n} Gaussians",
            groups.len()
        )));
    }
    if let Some(&g) = groups.iter().find(|&&g| g < -1 || g >= count as i32) {
        return Err(CoreError::input(format!(
            "group {g} is neither -1 (none) nor one of the {count} labelled groups"
        )));
    }
    if labels.len() != width as usize * height as usize {
        return Err(CoreError::input(format!(
            "the label map has {} pixels, the image {width} x {height}",
            labels.len()
        )));
    }
    Ok(())
}

/// Each group's members in depth order: `order`'s entries by group (those of none
/// dropped), each group's in `order`'s order (a stable counting sort).
fn group_orders(order: &[u32], groups: &[i32], count: usize) -> Vec<Vec<u32>> {
    let group = |i: u32| usize::try_from(groups[i as usize]).ok();
    let mut sizes = vec![0usize; count];
    for g in order.iter().filter_map(|&i| group(i)) {
        sizes[g] += 1;
    }
    let mut out: Vec<Vec<u32>> = sizes.iter().map(|&n| Vec::with_capacity(n)).collect();
    for &i in order {
        if let Some(g) = group(i) {
            out[g].push(i);
        }
    }
    out
}

/// (flagged pixels, flagged pixels labelled `label`) of the tile just blended.
fn count_flagged(
    scratch: &TileScratch,
    rect: &TileRect,
    width: u32,
    labels: &[i32],
    label: i32,
) -> (u64, u64) {
    let (mut alone, mut visible) = (0u64, 0u64);
    let tw = (rect.x1 - rect.x0) as usize;
    for y in rect.y0..rect.y1 {
        let ly = (y - rect.y0) as usize;
        let trans = &scratch.trans[ly * scratch.geo.stride..][..tw];
        let row = &labels[y as usize * width as usize + rect.x0 as usize..][..tw];
        for (t, &l) in trans.iter().zip(row) {
            // A flagged pixel's transmittance carries the sign bit (`TileScratch::trans`).
            let inside = t.is_sign_negative();
            alone += inside as u64;
            visible += (inside & (l == label)) as u64;
        }
    }
    (alone, visible)
}

#[cfg(test)]
mod tests {
    use super::super::camera::Camera;
    use super::super::forward_pass::forward;
    use super::super::scene::{ColorMode, Scene};
    use super::*;
    use crate::test_rng::Lcg;

    /// Gaussians in `groups` clusters, overlapping on screen, each with a random opacity
    /// range, and a last cluster of none (group -1), interleaved; a camera looking down +z
    /// at them, 70 x 50 pixels. One constant colour channel.
    fn scene(seed: u64, groups: usize, per: usize) -> (Scene, Vec<i32>, Camera) {
        let mut r = Lcg::new(seed);
        let (mut means, mut quats, mut scales, mut opacities) = (vec![], vec![], vec![], vec![]);
        let mut group = vec![];
        for g in 0..=groups {
            let (cx, cy) = (r.uniform() - 0.5, r.uniform() - 0.5);
            let faint = r.uniform();
            for _ in 0..per {
                means.extend([
                    cx + 0.6 * (r.uniform() - 0.5),
                    cy + 0.6 * (r.uniform() - 0.5),
                ]);
                means.push(0.5 * (r.uniform() - 0.5));
                quats.extend((0..4).map(|_| r.uniform() - 0.5));
                scales.extend((0..3).map(|_| 0.005 + 0.08 * r.uniform()));
                opacities.push(faint * 0.3 + 0.7 * r.uniform());
                group.push(if g == groups { -1 } else { g as i32 });
            }
        }
        let n = group.len();
        let mut perm: Vec<usize> = (0..n).collect();
        for i in (1..n).rev() {
            perm.swap(i, (r.uniform() * (i + 1) as f32) as usize % (i + 1));
        }
        let (s, group) = (
            subset(&means, &quats, &scales, &opacities, &perm),
            perm.iter().map(|&i| group[i]).collect(),
        );
        let view = [
            1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 3.0, 0.0, 0.0, 0.0, 1.0,
        ];
        let k = [55.0, 0.0, 35.5, 0.0, 55.0, 24.0, 0.0, 0.0, 1.0];
        (s, group, Camera::from_matrices(&view, &k, 70, 50).unwrap())
    }

    /// The Gaussians `keep` of the arrays, in that order, with one constant channel.
    fn subset(
        means: &[f32],
        quats: &[f32],
        scales: &[f32],
        opacities: &[f32],
        keep: &[usize],
    ) -> Scene {
        let rows = |v: &[f32], w: usize| -> Vec<f32> {
            keep.iter()
                .flat_map(|&i| v[w * i..w * i + w].to_vec())
                .collect()
        };
        let ones = vec![1.0; keep.len()];
        let mode = ColorMode::Direct { channels: 1 };
        Scene::new(
            &rows(means, 3),
            &rows(quats, 4),
            &rows(scales, 3),
            &rows(opacities, 1),
            &ones,
            mode,
        )
        .unwrap()
    }

    /// One group's Gaussians alone through `forward`: its alpha image.
    fn alone_alpha(
        scene: &Scene,
        groups: &[i32],
        g: i32,
        cam: &Camera,
        opts: RasterOptions,
    ) -> Vec<f32> {
        let keep: Vec<usize> = (0..scene.n).filter(|&i| groups[i] == g).collect();
        let mine = subset(
            &scene.means,
            &scene.quats,
            &scene.scales,
            &scene.opacities,
            &keep,
        );
        forward(mine, vec![*cam], cam.width, cam.height, opts)
            .unwrap()
            .0
            .alpha
    }

    fn state_of(scene: &Scene, cam: &Camera, opts: RasterOptions) -> ForwardState {
        forward(scene.clone(), vec![*cam], cam.width, cam.height, opts)
            .unwrap()
            .1
    }

    #[test]
    fn each_group_is_its_own_render_thresholded() {
        // (seed, threshold, the pass's tile size, the groups' tile size, SIMD)
        let cases = [
            (1, 0.5, 32, 16, true),
            (2, 0.5, 16, 16, false),
            (3, 0.3, 16, 8, true),
            (4, 0.9, 8, 32, true),
            (5, 0.5, 32, 5, true),
        ];
        for (seed, threshold, pass_tile, tile_size, simd) in cases {
            let (scene, groups, cam) = scene(seed, 5, 60);
            let opts = RasterOptions {
                tile_size: pass_tile,
                simd,
                ..RasterOptions::default()
            };
            let state = state_of(&scene, &cam, opts);
            // Labels: each pixel the first group whose alone alpha passes 0.6, a stand-in
            // for a view's instance map; -1 where none does.
            let alphas: Vec<Vec<f32>> = (0..5)
                .map(|g| alone_alpha(&scene, &groups, g, &cam, opts))
                .collect();
            let labels: Vec<i32> = (0..alphas[0].len())
                .map(|p| {
                    (0..5)
                        .find(|&g| alphas[g][p] > 0.6)
                        .map_or(-1, |g| 10 + g as i32)
                })
                .collect();
            let group_labels: Vec<i32> = (10..15).collect();
            let map = LabelMap {
                labels: &labels,
                group_labels: &group_labels,
            };
            let got = group_coverage(&state, 0, &groups, tile_size, threshold, map).unwrap();
            for (g, alpha) in alphas.iter().enumerate() {
                let inside: Vec<bool> = alpha.iter().map(|&a| a >= threshold).collect();
                let alone = inside.iter().filter(|&&i| i).count() as u64;
                let visible = inside
                    .iter()
                    .zip(&labels)
                    .filter(|(&i, &l)| i && l == 10 + g as i32)
                    .count() as u64;
                assert!(
                    alone > 0,
                    "seed {seed} group {g}: an empty silhouette proves nothing"
                );
                assert_eq!(
                    (got.alone[g], got.visible[g]),
                    (alone, visible),
                    "seed {seed} group {g}"
                );
            }
            assert!(
                got.visible.iter().zip(&got.alone).any(|(v, a)| v < a),
                "some group partly hidden"
            );
        }
    }

    #[test]
    fn counts_do_not_depend_on_the_thread_count() {
        let (scene, groups, cam) = scene(7, 6, 80);
        let state = state_of(&scene, &cam, RasterOptions::default());
        let labels = vec![2i32; 70 * 50];
        let group_labels: Vec<i32> = (0..6).collect();
        let map = LabelMap {
            labels: &labels,
            group_labels: &group_labels,
        };
        let run = |n| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap();
            pool.install(|| group_coverage(&state, 0, &groups, 16, 0.5, map).unwrap())
        };
        let one = run(1);
        assert_eq!(one, run(3));
        assert_eq!(one.visible.iter().sum::<u64>(), one.alone[2]);
    }

    #[test]
    fn stop_transmittance_is_the_last_passing_value() {
        for threshold in [0.5f32, 0.3, 0.9, 1.0, 1e-6, 0.123_456_7] {
            let t = stop_transmittance(threshold).unwrap();
            assert!(1.0 - t >= threshold, "{threshold}");
            assert!(
                1.0 - f32::from_bits(t.to_bits() + 1) < threshold,
                "{threshold}"
            );
        }
        assert_eq!(stop_transmittance(0.5).unwrap(), 0.5);
        for bad in [0.0, -0.5, 1.5, f32::NAN] {
            assert!(stop_transmittance(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn bad_inputs_are_errors() {
        let (scene, groups, cam) = scene(9, 2, 10);
        let state = state_of(&scene, &cam, RasterOptions::default());
        let labels = vec![0i32; 70 * 50];
        let two = [0i32, 1];
        let map = LabelMap {
            labels: &labels,
            group_labels: &two,
        };
        let err = |r: CoreResult<Coverage>| r.unwrap_err().to_string();
        assert!(err(group_coverage(&state, 0, &groups[1..], 16, 0.5, map)).contains("groups has"));
        let one = LabelMap {
            labels: &labels,
            group_labels: &two[..1],
        };
        assert!(err(group_coverage(&state, 0, &groups, 16, 0.5, one)).contains("neither -1"));
        let short = LabelMap {
            labels: &labels[1..],
            group_labels: &two,
        };
        assert!(err(group_coverage(&state, 0, &groups, 16, 0.5, short)).contains("label map"));
        assert!(err(group_coverage(&state, 1, &groups, 16, 0.5, map)).contains("camera 1"));
        assert!(err(group_coverage(&state, 0, &groups, 1, 0.5, map)).contains("tile_size"));
        assert!(err(group_coverage(&state, 0, &groups, 16, 0.0, map)).contains("threshold"));
        let coarse = state_of(
            &scene,
            &cam,
            RasterOptions {
                t_min: 0.01,
                ..RasterOptions::default()
            },
        );
        assert!(err(group_coverage(&coarse, 0, &groups, 16, 0.5, map)).contains("t_min"));
    }
}
