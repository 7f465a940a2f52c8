//! Backward pass against central finite differences of the forward pass, every parameter.
//!
//! The scenes are built so the image is smooth in every parameter: a few large splats near
//! the image centre, so every pixel lies inside every alpha >= 1/255 contour, opacities
//! below the 0.99 clamp and too few layers to reach the T <= 1e-4 stop.

mod common;

use common::{axis_camera, Params, Rng};
use splat_core::raster::{self, ColorMode, GradRequest, RasterOptions};

const SIZE: u32 = 20;

fn smooth_scene(rng: &mut Rng, mode: ColorMode) -> Params {
    let n = 4;
    let mut p = Params {
        means: (0..3 * n).map(|_| 0.1 * rng.normal()).collect(),
        quats: (0..4 * n).map(|_| rng.normal()).collect(),
        scales: (0..3 * n).map(|_| rng.range(0.6, 0.9)).collect(),
        opacities: (0..n).map(|_| rng.range(0.3, 0.7)).collect(),
        colors: Vec::new(),
        mode,
    };
    let width = match mode {
        ColorMode::Direct { channels } => channels,
        ColorMode::Sh { bases, .. } => 3 * bases,
        ColorMode::None => 0,
    };
    p.colors = (0..n * width).map(|_| 0.3 * rng.normal() + 0.2).collect();
    p
}

/// Weighted sum of render and alpha, in f64.
fn loss(p: &Params, opts: RasterOptions, w: &[f64], wa: &[f64]) -> f64 {
    let cam = axis_camera(SIZE, 22.0, 2.5);
    let (out, _) = raster::forward(p.scene(), vec![cam], SIZE, SIZE, opts).unwrap();
    let a: f64 = out.render.iter().zip(w).map(|(x, w)| *x as f64 * w).sum();
    let b: f64 = out.alpha.iter().zip(wa).map(|(x, w)| *x as f64 * w).sum();
    a + b
}

fn check(mode: ColorMode, opts: RasterOptions, seed: u64) {
    let mut rng = Rng::new(seed);
    let p = smooth_scene(&mut rng, mode);
    let cam = axis_camera(SIZE, 22.0, 2.5);
    let (out, state) = raster::forward(p.scene(), vec![cam], SIZE, SIZE, opts).unwrap();
    let w: Vec<f64> = out.render.iter().map(|_| rng.normal() as f64).collect();
    let wa: Vec<f64> = out.alpha.iter().map(|_| rng.normal() as f64).collect();
    let vr: Vec<f32> = w.iter().map(|&x| x as f32).collect();
    let va: Vec<f32> = wa.iter().map(|&x| x as f32).collect();
    let want = GradRequest {
        means: true,
        quats: true,
        scales: true,
        opacities: true,
        colors: true,
    };
    let g = raster::backward(&state, &vr, Some(&va), want).unwrap();
    let groups = [g.means, g.quats, g.scales, g.opacities, g.colors];
    for (gi, grad) in groups.iter().enumerate() {
        let Some(grad) = grad else { continue };
        for (i, &analytic) in grad.iter().enumerate() {
            let h = 1e-3f32;
            let mut plus = p.clone();
            plus.group(gi)[i] += h;
            let mut minus = p.clone();
            minus.group(gi)[i] -= h;
            let fd = (loss(&plus, opts, &w, &wa) - loss(&minus, opts, &w, &wa)) / (2.0 * h as f64);
            let tol = 3e-3 * (1.0 + analytic.abs() as f64);
            assert!(
                (fd - analytic as f64).abs() <= tol,
                "group {gi} index {i}: finite difference {fd} vs backward {analytic}"
            );
        }
    }
}

#[test]
fn direct_colours_with_depth() {
    let opts = RasterOptions {
        with_depth: true,
        ..common::default_opts()
    };
    check(ColorMode::Direct { channels: 3 }, opts, 1);
}

#[test]
fn sh_degree_three() {
    check(
        ColorMode::Sh {
            degree: 3,
            bases: 16,
        },
        common::default_opts(),
        2,
    );
}

#[test]
fn antialiased_depth_only() {
    let opts = RasterOptions {
        antialiased: true,
        with_depth: true,
        ..common::default_opts()
    };
    check(ColorMode::None, opts, 3);
}

#[test]
fn five_feature_channels() {
    check(ColorMode::Direct { channels: 5 }, common::default_opts(), 4);
}
