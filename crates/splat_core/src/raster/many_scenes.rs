//! Many independent scenes in one call (a trainer's plants): their forward passes, or their
//! backward passes, run side by side on one pool, each scene's work parallel over its
//! tiles as in a call of its own.
//!
//! Each scene gets exactly the bits of its own `forward` / `backward` call, on any thread
//! count (the passes' outputs never depend on how their work is split), and its own
//! result: a scene with bad input fails alone, the others are rendered.

use rayon::prelude::*;

use super::backward_pass::{backward, GradRequest, Gradients};
use super::camera::Camera;
use super::forward_pass::{forward, forward_with_background, ForwardOutput, ForwardState};
use super::options::RasterOptions;
use super::scene::Scene;
use crate::CoreResult;

/// One scene of a `forward_many` call: what `forward` takes besides the options, and the
/// background of `forward_with_background` if any.
#[derive(Debug, Clone)]
pub struct SceneJob {
    pub scene: Scene,
    pub cameras: Vec<Camera>,
    pub width: u32,
    pub height: u32,
    pub background: Option<Vec<f32>>,
}

/// One scene's result, or the error of that scene alone.
pub type ForwardResult = CoreResult<(ForwardOutput, ForwardState)>;

/// `forward` of every job, in the jobs' order. The jobs run in parallel on the current
/// pool (`threads::with_threads`), each also parallel inside.
pub fn forward_many(jobs: Vec<SceneJob>, opts: RasterOptions) -> Vec<ForwardResult> {
    jobs.into_par_iter()
        .map(|j| forward_scene(j, opts))
        .collect()
}

/// One job's `forward`, or `forward_with_background` when it has a background.
pub fn forward_scene(j: SceneJob, opts: RasterOptions) -> ForwardResult {
    match j.background {
        Some(bg) => forward_with_background(j.scene, j.cameras, j.width, j.height, opts, bg),
        None => forward(j.scene, j.cameras, j.width, j.height, opts),
    }
}

/// One scene of a `backward_many` call: its forward state and the gradients of its
/// render [C, H, W, ch] and alpha [C, H, W] (None: none, as in `backward`).
#[derive(Debug, Clone, Copy)]
pub struct BackwardJob<'a> {
    pub state: &'a ForwardState,
    pub v_render: &'a [f32],
    pub v_alpha: Option<&'a [f32]>,
}

/// `backward` of every job, in the jobs' order, in parallel as `forward_many`.
pub fn backward_many(jobs: &[BackwardJob<'_>], want: GradRequest) -> Vec<CoreResult<Gradients>> {
    jobs.par_iter()
        .map(|j| backward(j.state, j.v_render, j.v_alpha, want))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::scene::ColorMode;
    use super::*;
    use crate::test_rng::Lcg;
    use crate::threads::with_threads;

    /// A random scene of `n` Gaussians before a camera looking down +z, 40 x 36 pixels.
    fn job(seed: u64, n: usize) -> SceneJob {
        let mut r = Lcg::new(seed);
        let mut u = |k: usize, lo: f32, hi: f32| -> Vec<f32> {
            (0..k).map(|_| lo + (hi - lo) * r.uniform()).collect()
        };
        let (means, quats) = (u(3 * n, -1.0, 1.0), u(4 * n, -0.5, 0.5));
        let (scales, opacities) = (u(3 * n, 0.01, 0.12), u(n, 0.1, 1.0));
        let sh = u(n * 4 * 3, -0.5, 0.5);
        let mode = ColorMode::Sh {
            degree: 1,
            bases: 4,
        };
        let scene = Scene::new(&means, &quats, &scales, &opacities, &sh, mode).unwrap();
        let view = [
            1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 4.0, 0.0, 0.0, 0.0, 1.0,
        ];
        let k = [50.0, 0.0, 20.0, 0.0, 50.0, 18.0, 0.0, 0.0, 1.0];
        let camera = Camera::from_matrices(&view, &k, 40, 36).unwrap();
        SceneJob {
            scene,
            cameras: vec![camera],
            width: 40,
            height: 36,
            background: None,
        }
    }

    fn opts() -> RasterOptions {
        RasterOptions {
            with_depth: true,
            ..RasterOptions::default()
        }
    }

    const ALL: GradRequest = GradRequest {
        means: true,
        quats: true,
        scales: true,
        opacities: true,
        colors: true,
    };

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// Every output bit of a forward and its backward (seeded render gradients).
    fn fingerprint(out: &ForwardOutput, grads: &Gradients) -> Vec<u32> {
        let mut all = bits(&out.render);
        all.extend(bits(&out.alpha));
        all.extend(bits(&out.means2d));
        all.extend(bits(&out.depths));
        all.extend(out.radii.iter().map(|&r| r as u32));
        for g in [
            &grads.means,
            &grads.quats,
            &grads.scales,
            &grads.opacities,
            &grads.colors,
        ] {
            all.extend(bits(g.as_deref().unwrap()));
        }
        all.extend(bits(&grads.means2d));
        all
    }

    fn upstream(out: &ForwardOutput, seed: u64) -> (Vec<f32>, Vec<f32>) {
        let mut r = Lcg::new(seed);
        let vr = out.render.iter().map(|_| 2.0 * r.uniform() - 1.0).collect();
        let va = out.alpha.iter().map(|_| 2.0 * r.uniform() - 1.0).collect();
        (vr, va)
    }

    /// Each scene alone: forward, then backward, on one thread.
    fn separate(jobs: &[SceneJob]) -> Vec<Vec<u32>> {
        with_threads(Some(1), || {
            Ok(jobs
                .iter()
                .enumerate()
                .map(|(i, j)| {
                    let (out, st) = forward(
                        j.scene.clone(),
                        j.cameras.clone(),
                        j.width,
                        j.height,
                        opts(),
                    )
                    .unwrap();
                    let (vr, va) = upstream(&out, 100 + i as u64);
                    fingerprint(&out, &backward(&st, &vr, Some(&va), ALL).unwrap())
                })
                .collect())
        })
        .unwrap()
    }

    /// All scenes in one forward_many call and one backward_many call.
    fn together(jobs: &[SceneJob], threads: usize) -> Vec<Vec<u32>> {
        with_threads(Some(threads), || {
            let done: Vec<_> = forward_many(jobs.to_vec(), opts())
                .into_iter()
                .map(Result::unwrap)
                .collect();
            let ups: Vec<_> = done
                .iter()
                .enumerate()
                .map(|(i, (out, _))| upstream(out, 100 + i as u64))
                .collect();
            let back: Vec<_> = done
                .iter()
                .zip(&ups)
                .map(|((_, st), (vr, va))| BackwardJob {
                    state: st,
                    v_render: vr,
                    v_alpha: Some(va),
                })
                .collect();
            let grads = backward_many(&back, ALL);
            Ok(done
                .iter()
                .zip(grads)
                .map(|((out, _), g)| fingerprint(out, &g.unwrap()))
                .collect())
        })
        .unwrap()
    }

    #[test]
    fn many_scenes_give_each_scene_its_own_bits_on_any_thread_count() {
        let jobs: Vec<_> = (0..5).map(|i| job(7 + i, 150 + 40 * i as usize)).collect();
        let alone = separate(&jobs);
        assert!(alone.iter().all(|f| f.iter().any(|&b| b != 0)));
        for threads in [1, 2, 3, 4, 8] {
            assert_eq!(together(&jobs, threads), alone, "{threads} threads");
        }
    }

    #[test]
    fn a_bad_scene_fails_alone() {
        let mut jobs: Vec<_> = (0..3).map(|i| job(20 + i, 120)).collect();
        jobs[1].width = 0; // the image size check of `forward`
        let done = forward_many(jobs.clone(), opts());
        assert!(done[0].is_ok() && done[2].is_ok());
        let err = done[1].as_ref().err().unwrap().to_string();
        assert!(err.contains("image size must be positive"), "{err}");
        let (out, _) = done[2].as_ref().unwrap();
        let (alone, _) = forward(
            jobs[2].scene.clone(),
            jobs[2].cameras.clone(),
            40,
            36,
            opts(),
        )
        .unwrap();
        assert_eq!(bits(&out.render), bits(&alone.render));

        // A wrong-length upstream gradient fails its scene's backward only.
        let states: Vec<_> = [&done[0], &done[2]]
            .map(|d| &d.as_ref().unwrap().1)
            .to_vec();
        let short = vec![0.0f32; 3];
        let (vr, va) = upstream(&done[0].as_ref().unwrap().0, 1);
        let back = [
            BackwardJob {
                state: states[0],
                v_render: &vr,
                v_alpha: Some(&va),
            },
            BackwardJob {
                state: states[1],
                v_render: &short,
                v_alpha: Some(&va),
            },
        ];
        let grads = backward_many(&back, ALL);
        assert!(grads[0].is_ok());
        assert!(grads[1]
            .as_ref()
            .err()
            .unwrap()
            .to_string()
            .contains("v_render"));
    }

    #[test]
    fn scenes_with_backgrounds_give_each_its_own_bits() {
        let plain = RasterOptions::default(); // colours only: a background needs no depth
        let jobs: Vec<_> = (0..3)
            .map(|i| SceneJob {
                background: (i != 1).then(|| vec![0.25, 0.5 + 0.1 * i as f32, 1.0]),
                ..job(40 + i, 130)
            })
            .collect();
        for threads in [1, 3] {
            let done = with_threads(Some(threads), || Ok(forward_many(jobs.clone(), plain)));
            for (j, d) in jobs.iter().zip(done.unwrap()) {
                let (out, st) = d.unwrap();
                let (alone, alone_st) =
                    with_threads(Some(1), || forward_scene(j.clone(), plain)).unwrap();
                assert_eq!(bits(&out.render), bits(&alone.render));
                let (vr, va) = upstream(&out, 5);
                for v_alpha in [None, Some(&va[..])] {
                    let job = BackwardJob {
                        state: &st,
                        v_render: &vr,
                        v_alpha,
                    };
                    let g = backward_many(&[job], ALL).remove(0).unwrap();
                    let g_alone = backward(&alone_st, &vr, v_alpha, ALL).unwrap();
                    assert_eq!(fingerprint(&out, &g), fingerprint(&alone, &g_alone));
                }
            }
        }
    }

    #[test]
    fn a_background_is_the_plain_render_plus_bg_times_one_minus_alpha() {
        let plain = RasterOptions::default();
        let j = job(50, 140);
        let (out, st) = forward(j.scene.clone(), j.cameras.clone(), 40, 36, plain).unwrap();
        let bg = vec![0.2, 0.7, 0.0];
        let (over, over_st) = forward_with_background(
            j.scene.clone(),
            j.cameras.clone(),
            40,
            36,
            plain,
            bg.clone(),
        )
        .unwrap();
        let want: Vec<f32> = out
            .render
            .chunks_exact(3)
            .zip(&out.alpha)
            .flat_map(|(px, &a)| (0..3).map(move |k| px[k] + (1.0 - a) * [0.2, 0.7, 0.0][k]))
            .collect();
        assert_eq!(bits(&over.render), bits(&want));
        assert_eq!(bits(&over.alpha), bits(&out.alpha));
        // With no render gradient, the alpha's gradient is the caller's alone: v_alpha
        // reaches the Gaussians unchanged (plus -0 from the zero render gradient).
        let zeros = vec![0.0f32; out.render.len()];
        let (_, va) = upstream(&out, 9);
        let g_over = backward(&over_st, &zeros, Some(&va), ALL).unwrap();
        let g_plain = backward(&st, &zeros, Some(&va), ALL).unwrap();
        assert_eq!(g_over.opacities, g_plain.opacities);
        // A background for a depth channel, or of the wrong size, is refused.
        let depth = RasterOptions {
            with_depth: true,
            ..plain
        };
        let err = forward_with_background(j.scene.clone(), j.cameras.clone(), 40, 36, depth, bg)
            .unwrap_err();
        assert!(err.to_string().contains("depth channel"), "{err}");
        let err =
            forward_with_background(j.scene, j.cameras, 40, 36, plain, vec![0.5; 2]).unwrap_err();
        assert!(err.to_string().contains("background"), "{err}");
    }
}
