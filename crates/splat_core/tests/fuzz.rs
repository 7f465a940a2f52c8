//! Degenerate scenes must never panic or let NaN/Inf into images or gradients.

mod common;

use common::{axis_camera, Params, Rng};
use splat_core::raster::{self, ColorMode, GradRequest, RasterOptions};

fn degenerate_value(rng: &mut Rng) -> f32 {
    rng.pick(&[
        0.0,
        -0.0,
        1e-30,
        -1e-30,
        1e-7,
        1e4,
        -1e4,
        1e20,
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::MIN_POSITIVE,
    ])
}

/// Mostly ordinary values, sometimes a degenerate one.
fn value(rng: &mut Rng, ordinary: impl FnOnce(&mut Rng) -> f32) -> f32 {
    if rng.uniform() < 0.15 {
        degenerate_value(rng)
    } else {
        ordinary(rng)
    }
}

fn random_scene(rng: &mut Rng, n: usize, mode: ColorMode, dist: f32) -> Params {
    let mut means = Vec::new();
    for _ in 0..n {
        let kind = rng.uniform();
        let m = if kind < 0.1 {
            [0.0, 0.0, -dist] // exactly at the camera centre
        } else if kind < 0.2 {
            // z = near +- 1e-6 in camera space
            let z = 0.01 + rng.pick(&[-1e-6, 0.0, 1e-6]);
            [rng.range(-0.01, 0.01), rng.range(-0.01, 0.01), z - dist]
        } else if kind < 0.25 {
            [0.0, 0.0, 1e9] // very distant
        } else {
            [
                value(rng, |r| r.normal()),
                value(rng, |r| r.normal()),
                value(rng, |r| r.normal()),
            ]
        };
        means.extend(m);
    }
    let quats = (0..4 * n)
        .map(|_| {
            if rng.uniform() < 0.1 {
                rng.pick(&[0.0, 1e-20, 1e-12, 1e-6])
            } else {
                value(rng, |r| r.normal())
            }
        })
        .collect();
    let scales = (0..3 * n)
        .map(|_| value(rng, |r| 10f32.powf(r.range(-7.0, 4.0))))
        .collect();
    let opacities = (0..n)
        .map(|_| {
            value(rng, |r| {
                r.pick(&[0.0, 1.0 / 255.0, 0.5, 0.99, 1.0, 1.5, -0.2])
            })
        })
        .collect();
    let width = match mode {
        ColorMode::Direct { channels } => channels,
        ColorMode::Sh { bases, .. } => 3 * bases,
        ColorMode::None => 0,
    };
    // Colours: NaN/Inf (culled) or large, but not so large that products overflow f32.
    let colors = (0..n * width)
        .map(|_| {
            if rng.uniform() < 0.1 {
                rng.pick(&[f32::NAN, f32::INFINITY, 1e4, -1e4, 0.0])
            } else {
                rng.normal()
            }
        })
        .collect();
    Params {
        means,
        quats,
        scales,
        opacities,
        colors,
        mode,
    }
}

fn all_finite(xs: &[f32]) -> bool {
    xs.iter().all(|v| v.is_finite())
}

#[test]
fn degenerate_scenes_give_finite_images_and_gradients() {
    let mut rng = Rng::new(7);
    let all = GradRequest {
        means: true,
        quats: true,
        scales: true,
        opacities: true,
        colors: true,
    };
    for round in 0..300 {
        let mode = rng.pick(&[
            ColorMode::Direct { channels: 3 },
            ColorMode::Sh {
                degree: 3,
                bases: 16,
            },
            ColorMode::Sh {
                degree: 1,
                bases: 4,
            },
        ]);
        let n = rng.pick(&[1usize, 2, 8, 40]);
        let dist = 3.0;
        let p = random_scene(&mut rng, n, mode, dist);
        let size = rng.pick(&[1u32, 7, 33]);
        let cam = axis_camera(size, rng.pick(&[1.0, 30.0, 1e4]), dist);
        let opts = RasterOptions {
            with_depth: true,
            antialiased: round % 2 == 1,
            tile_size: rng.pick(&[2, 8, 16]),
            ..RasterOptions::default()
        };
        let (out, state) = raster::forward(p.scene(), vec![cam], size, size, opts).unwrap();
        assert!(
            all_finite(&out.render) && all_finite(&out.alpha),
            "round {round}"
        );
        assert!(out.alpha.iter().all(|a| (0.0..=1.0).contains(a)));
        let vr: Vec<f32> = out.render.iter().map(|_| rng.normal()).collect();
        let va: Vec<f32> = out.alpha.iter().map(|_| rng.normal()).collect();
        let g = raster::backward(&state, &vr, Some(&va), all).unwrap();
        for (name, grad) in [
            ("means", g.means),
            ("quats", g.quats),
            ("scales", g.scales),
            ("opacities", g.opacities),
            ("colors", g.colors),
            ("means2d", Some(g.means2d)),
        ] {
            let grad = grad.unwrap();
            if !all_finite(&grad) {
                let w = grad.len() / p.opacities.len();
                let i = grad.iter().position(|v| !v.is_finite()).unwrap() / w;
                panic!(
                    "round {round}: {name} of Gaussian {i}: mean {:?} quat {:?} scale {:?} opacity {} camera focal {} size {size}",
                    &p.means[3 * i..3 * i + 3],
                    &p.quats[4 * i..4 * i + 4],
                    &p.scales[3 * i..3 * i + 3],
                    p.opacities[i],
                    cam.fx
                );
            }
        }
    }
}

#[test]
fn opaque_stack_on_one_pixel_has_finite_gradients() {
    // 64 opacity-1 splats on one pixel: alpha clamps at 0.99 and T collapses; the
    // 1/(1 - alpha) recovery must stay finite.
    let n = 64;
    let p = Params {
        means: (0..n).flat_map(|i| [0.0, 0.0, i as f32 * 1e-3]).collect(),
        quats: (0..n).flat_map(|_| [1.0, 0.0, 0.0, 0.0]).collect(),
        scales: vec![0.05; 3 * n],
        opacities: vec![1.0; n],
        colors: vec![0.7; 3 * n],
        mode: ColorMode::Direct { channels: 3 },
    };
    let cam = axis_camera(9, 40.0, 3.0);
    let (out, state) =
        raster::forward(p.scene(), vec![cam], 9, 9, RasterOptions::default()).unwrap();
    let centre = 4 * 9 + 4;
    // Two layers at alpha 0.99 leave T = 1e-4: the stop rule keeps alpha at 0.99.
    assert!(out.alpha[centre] >= 0.99 - 1e-6);
    let g = raster::backward(
        &state,
        &vec![1.0; out.render.len()],
        Some(&vec![1.0; out.alpha.len()]),
        GradRequest {
            means: true,
            quats: true,
            scales: true,
            opacities: true,
            colors: true,
        },
    )
    .unwrap();
    for v in [g.means, g.quats, g.scales, g.opacities, g.colors] {
        assert!(all_finite(&v.unwrap()));
    }
}

#[test]
fn bad_options_are_input_errors() {
    let p = Params {
        means: vec![0.0; 3],
        quats: vec![1.0, 0.0, 0.0, 0.0],
        scales: vec![0.1; 3],
        opacities: vec![0.5],
        colors: vec![0.5; 3],
        mode: ColorMode::Direct { channels: 3 },
    };
    let cam = axis_camera(8, 10.0, 3.0);
    for opts in [
        RasterOptions {
            near_plane: 0.0,
            ..RasterOptions::default()
        },
        RasterOptions {
            tile_size: 0,
            ..RasterOptions::default()
        },
        RasterOptions {
            t_min: f32::NAN,
            ..RasterOptions::default()
        },
    ] {
        let err = raster::forward(p.scene(), vec![cam], 8, 8, opts).unwrap_err();
        assert!(matches!(err, splat_core::CoreError::Input(_)), "{err}");
    }
}
