//! 3D Gaussian Splatting rasterizer on the CPU: gsplat 1.5 "classic" semantics, forward and
//! backward, rayon-parallel and bit-identical for any thread count.
//!
//! Pipeline per camera: `project_batch` (EWA splats, eight Gaussians at a time; `project`
//! is the per-Gaussian reference) -> `features` (SH colour / depth)
//! -> `tile_binning` (depth order, tile lists) -> `forward::blend` (per-tile compositing).
//! `backward` walks the same lists back to front and chains to the 3D parameters.
//!
//! The blending kernels (`forward`, `backward`) run on groups of eight pixels: AVX2 code in
//! `blend_avx2` where the CPU has it, a scalar version of the same operations otherwise;
//! both give the same bits (tested).
//!
//! State kept between forward and backward (`ForwardState`): a copy of the inputs
//! (O(N)), and per camera the splats and features (O(N)), the tile lists
//! (O(intersections)), and the final transmittance and last-contributor count per pixel
//! (O(pixels)). Nothing per (pixel, splat) pair is
//! stored.

pub mod backward;
#[cfg(target_arch = "x86_64")]
mod blend_avx2;
pub mod camera;
pub mod features;
pub mod forward;
pub mod gradients;
#[cfg(all(test, target_arch = "x86_64"))]
mod kernel_tests;
pub mod project;
mod project_batch;
pub mod scene;
pub mod sh;
pub mod tile_binning;

use std::time::Instant;

use rayon::prelude::*;

pub use camera::Camera;
pub use gradients::{backward, GradRequest, Gradients};
pub use scene::{ColorMode, Scene};

use crate::{CoreError, CoreResult};
use forward::Blended;
use project::Splat;
use tile_binning::TileBins;

/// Splats fainter than this at a pixel are skipped (and culled when their opacity is).
pub const ALPHA_MIN: f32 = 1.0 / 255.0;
/// Per-splat alpha is clamped to this.
pub const ALPHA_MAX: f32 = 0.99;

/// How far a splat's footprint reaches, in standard deviations per axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Footprint {
    /// min(3.33, sqrt(2 ln(255 opacity))): the exact box of the alpha = 1/255 contour.
    OpacityAware,
    /// A fixed number of standard deviations (3.0 was the original 3DGS rule).
    Sigma(f32),
}

/// Rasterization settings; the defaults are gsplat 1.5's.
#[derive(Debug, Clone, Copy)]
pub struct RasterOptions {
    pub near_plane: f32,
    pub far_plane: f32,
    pub eps2d: f32,
    /// Multiply opacity by sqrt(det(Sigma) / det(Sigma + eps2d I)) ("antialiased" mode).
    pub antialiased: bool,
    pub tile_size: u32,
    pub footprint: Footprint,
    /// Keep only tiles the footprint ellipse touches, not every tile of its box.
    pub tile_ellipse: bool,
    /// Stop blending a pixel before the splat that would bring T to <= t_min.
    pub t_min: f32,
    /// Append the camera-space depth as the last feature channel.
    pub with_depth: bool,
    /// Blend with the SIMD kernels where the CPU has them; false forces the scalar kernels
    /// (the same bits, slower: for checking and timing).
    pub simd: bool,
}

impl Default for RasterOptions {
    fn default() -> Self {
        Self {
            near_plane: 0.01,
            far_plane: 1e10,
            eps2d: 0.3,
            antialiased: false,
            tile_size: 16,
            footprint: Footprint::OpacityAware,
            tile_ellipse: true,
            t_min: 1e-4,
            with_depth: false,
            simd: true,
        }
    }
}

impl RasterOptions {
    fn validate(&self) -> CoreResult<()> {
        // far_plane may be +inf; a NaN far_plane fails the ordering check below.
        let finite = [self.near_plane, self.eps2d, self.t_min];
        if !finite.iter().all(|v| v.is_finite()) {
            return Err(CoreError::input(
                "near_plane, eps2d and t_min must be finite",
            ));
        }
        if !(self.near_plane > 0.0 && self.far_plane > self.near_plane) {
            return Err(CoreError::input(format!(
                "need 0 < near_plane < far_plane, got {} and {}",
                self.near_plane, self.far_plane
            )));
        }
        if self.eps2d.is_nan() || self.eps2d < 0.0 {
            return Err(CoreError::input("eps2d must be >= 0"));
        }
        if !(2..=64).contains(&self.tile_size) {
            return Err(CoreError::input(format!(
                "tile_size must be in 2..=64, got {}",
                self.tile_size
            )));
        }
        if !(0.0..1.0).contains(&self.t_min) {
            return Err(CoreError::input("t_min must be in [0, 1)"));
        }
        if let Footprint::Sigma(k) = self.footprint {
            if !(k > 0.0 && k.is_finite()) {
                return Err(CoreError::input("footprint sigma must be positive"));
            }
        }
        Ok(())
    }
}

/// The blending kernel this CPU runs with `simd` on: "avx2" or "scalar".
pub fn blend_kernel() -> &'static str {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        return "avx2";
    }
    "scalar"
}

/// Seconds spent in each stage, summed over cameras.
#[derive(Debug, Clone, Copy, Default)]
pub struct Profile {
    pub project: f64,
    pub sort: f64,
    pub bin: f64,
    pub blend: f64,
}

/// Per-camera blend state the backward pass needs.
#[derive(Debug, Clone)]
pub struct CameraState {
    pub splats: Vec<Splat>,
    pub features: Vec<f32>,
    pub bins: TileBins,
    pub blended: Blended,
}

/// Everything `backward` needs from the forward call.
#[derive(Debug, Clone)]
pub struct ForwardState {
    pub scene: Scene,
    pub cameras: Vec<Camera>,
    pub opts: RasterOptions,
    pub width: u32,
    pub height: u32,
    pub per_camera: Vec<CameraState>,
}

impl ForwardState {
    /// Feature channels per pixel (colour channels, then depth if requested).
    pub fn channels(&self) -> usize {
        self.scene.color_channels() + self.opts.with_depth as usize
    }
}

/// Images and per-Gaussian facts of a forward call. Arrays are row-major, camera first.
#[derive(Debug, Clone, Default)]
pub struct ForwardOutput {
    /// [C, H, W, ch]: blended features without background.
    pub render: Vec<f32>,
    /// [C, H, W]: 1 - final transmittance.
    pub alpha: Vec<f32>,
    /// [C, N, 2]: footprint half-sizes in pixels, 0 for culled Gaussians.
    pub radii: Vec<i32>,
    /// [C, N, 2]: projected centres in pixels (0 for culled Gaussians).
    pub means2d: Vec<f32>,
    /// [C, N]: camera-space depth (0 for culled Gaussians).
    pub depths: Vec<f32>,
    /// [C]: Gaussians that survived culling.
    pub n_visible: Vec<u64>,
    /// [C]: (tile, Gaussian) pairs blended.
    pub n_intersections: Vec<u64>,
    pub profile: Profile,
}

/// Renders every camera; returns the images and the state for `backward`.
pub fn forward(
    scene: Scene,
    cameras: Vec<Camera>,
    width: u32,
    height: u32,
    opts: RasterOptions,
) -> CoreResult<(ForwardOutput, ForwardState)> {
    opts.validate()?;
    if width == 0 || height == 0 {
        return Err(CoreError::input(format!(
            "image size must be positive, got {width}x{height}"
        )));
    }
    for cam in &cameras {
        if cam.width != width || cam.height != height {
            return Err(CoreError::Internal(
                "camera size differs from the image".into(),
            ));
        }
    }
    let ch = scene.color_channels() + opts.with_depth as usize;
    if ch == 0 {
        return Err(CoreError::input(
            "nothing to render: no colour and no depth channel",
        ));
    }
    camera::check_image_size(cameras.len(), width, height, ch)?;
    let (n, c) = (scene.n, cameras.len());
    let pixels = width as usize * height as usize;
    let mut out = ForwardOutput {
        render: vec![0.0; c * pixels * ch],
        alpha: vec![0.0; c * pixels],
        radii: vec![0; c * n * 2],
        means2d: vec![0.0; c * n * 2],
        depths: vec![0.0; c * n],
        ..Default::default()
    };
    let mut per_camera = Vec::with_capacity(c);
    for (ci, cam) in cameras.iter().enumerate() {
        let t0 = Instant::now();
        let splats = project_batch::project_all(&scene, cam, &opts);
        let feats = features::compute(&scene, cam, &splats, opts.with_depth);
        let t1 = Instant::now();
        let order = tile_binning::depth_order(&splats);
        let t2 = Instant::now();
        let bins = tile_binning::bin(
            &splats,
            order,
            width,
            height,
            opts.tile_size,
            opts.tile_ellipse,
        )?;
        let t3 = Instant::now();
        let blended = forward::blend(
            &splats,
            &feats,
            ch,
            &bins,
            width,
            height,
            opts.t_min,
            opts.simd,
            &mut out.render[ci * pixels * ch..(ci + 1) * pixels * ch],
            &mut out.alpha[ci * pixels..(ci + 1) * pixels],
        );
        let t4 = Instant::now();
        out.profile.project += (t1 - t0).as_secs_f64();
        out.profile.sort += (t2 - t1).as_secs_f64();
        out.profile.bin += (t3 - t2).as_secs_f64();
        out.profile.blend += (t4 - t3).as_secs_f64();

        out.radii[2 * ci * n..2 * (ci + 1) * n]
            .par_chunks_mut(2)
            .zip(out.means2d[2 * ci * n..2 * (ci + 1) * n].par_chunks_mut(2))
            .zip(&mut out.depths[ci * n..(ci + 1) * n])
            .zip(&splats)
            .filter(|(_, s)| s.visible())
            .for_each(|(((r, m), d), s)| {
                r.copy_from_slice(&s.radius.map(|v| v as i32));
                m.copy_from_slice(&s.xy);
                *d = s.depth;
            });
        out.n_visible.push(bins.depth_order.len() as u64);
        out.n_intersections.push(bins.n_intersections() as u64);
        per_camera.push(CameraState {
            splats,
            features: feats,
            bins,
            blended,
        });
    }
    let state = ForwardState {
        scene,
        cameras,
        opts,
        width,
        height,
        per_camera,
    };
    Ok((out, state))
}
