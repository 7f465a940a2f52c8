//! The forward pass over every camera: project, features, depth order, tile lists, blend.
//! Keeps what the backward pass needs (`ForwardState`).

use std::time::Instant;

use rayon::prelude::*;

use super::background;
use super::buffers::filled;
use super::camera::{self, Camera};
use super::forward_blend::{blend, Blended};
use super::options::RasterOptions;
use super::project::Splat;
use super::scene::Scene;
use super::tile_binning::{self, TileBins};
use super::tile_geometry::{blend_records, BlendRecord};
use super::{depth_sort, features, project_avx2};
use crate::error::check_len;
use crate::{CoreError, CoreResult};

/// Seconds spent in each stage, summed over cameras.
#[derive(Debug, Clone, Copy, Default)]
pub struct Profile {
    /// Projection to splats.
    pub project: f64,
    /// Depth sort, with the colour features, the blend's per-splat records and the
    /// per-Gaussian outputs computed beside it.
    pub sort: f64,
    pub bin: f64,
    pub blend: f64,
}

/// Per-camera blend state the backward pass needs.
#[derive(Debug, Clone)]
pub struct CameraState {
    pub splats: Vec<Splat>,
    pub features: Vec<f32>,
    /// The blend's per-splat records (None if the features are wider than a record),
    /// kept so that the backward's tile lists gather one cache line per entry too
    /// (64 bytes per Gaussian).
    pub records: Option<Vec<BlendRecord>>,
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
    /// [C, ch]: the background blended behind each camera's features, if any.
    pub background: Option<Vec<f32>>,
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
    /// [C, H, W, ch]: blended features (over the background when one was given).
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
        render: filled(c * pixels * ch, 0.0)?,
        alpha: filled(c * pixels, 0.0)?,
        radii: filled(c * n * 2, 0)?,
        means2d: filled(c * n * 2, 0.0)?,
        depths: filled(c * n, 0.0)?,
        ..Default::default()
    };
    let mut per_camera = Vec::with_capacity(c);
    for (ci, cam) in cameras.iter().enumerate() {
        let t0 = Instant::now();
        let splats = project_avx2::project_all(&scene, cam, &opts)?;
        let t1 = Instant::now();
        // The depth sort (itself parallel) runs beside the colour features, the blend's
        // per-splat records and the per-Gaussian outputs.
        let (order, features) = rayon::join(
            || depth_sort::depth_order(&splats),
            || {
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
                let feats = features::compute(&scene, cam, &splats, opts.with_depth)?;
                let records = blend_records(&splats, &feats, ch);
                Ok::<_, CoreError>((feats, records))
            },
        );
        let (feats, records) = features?;
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
        let (blended, _) = blend(
            &splats,
            &feats,
            records.as_deref(),
            ch,
            &bins,
            width,
            height,
            opts.t_min,
            opts.simd,
            false,
            &mut out.render[ci * pixels * ch..(ci + 1) * pixels * ch],
            &mut out.alpha[ci * pixels..(ci + 1) * pixels],
        )?;
        let t4 = Instant::now();
        out.profile.project += (t1 - t0).as_secs_f64();
        out.profile.sort += (t2 - t1).as_secs_f64();
        out.profile.bin += (t3 - t2).as_secs_f64();
        out.profile.blend += (t4 - t3).as_secs_f64();
        out.n_visible.push(bins.depth_order.len() as u64);
        out.n_intersections.push(bins.n_intersections() as u64);
        per_camera.push(CameraState {
            splats,
            features: feats,
            records,
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
        background: None,
    };
    Ok((out, state))
}

/// `forward` with a background behind each camera's features, `bg` [C, ch] (colour
/// channels only, no depth channel): the render is `features + bg (1 - alpha)`
/// (`background.rs`), and `backward` adds the alpha gradient the blend makes.
pub fn forward_with_background(
    scene: Scene,
    cameras: Vec<Camera>,
    width: u32,
    height: u32,
    opts: RasterOptions,
    bg: Vec<f32>,
) -> CoreResult<(ForwardOutput, ForwardState)> {
    if opts.with_depth {
        return Err(CoreError::input(
            "a background is blended behind colours only: the render has a depth channel",
        ));
    }
    let (c, ch) = (cameras.len(), scene.color_channels());
    check_len("background", &bg, c, ch)?;
    let (mut out, mut state) = forward(scene, cameras, width, height, opts)?;
    let pixels = width as usize * height as usize;
    for ci in 0..c {
        background::blend(
            &mut out.render[ci * pixels * ch..(ci + 1) * pixels * ch],
            &out.alpha[ci * pixels..(ci + 1) * pixels],
            &bg[ci * ch..(ci + 1) * ch],
        );
    }
    state.background = Some(bg);
    Ok((out, state))
}

#[cfg(test)]
mod tests {
    use super::super::scene::ColorMode;
    use super::*;
    use crate::test_rng::Lcg;

    /// 300 random Gaussians in front of a camera looking down +z, 48 x 40 pixels.
    fn scene_and_camera() -> (Scene, Camera) {
        let mut r = Lcg::new(11);
        let n = 300;
        let mut u = |k: usize, lo: f32, hi: f32| -> Vec<f32> {
            (0..k).map(|_| lo + (hi - lo) * r.uniform()).collect()
        };
        let (means, quats) = (u(3 * n, -1.0, 1.0), u(4 * n, -0.5, 0.5));
        let (scales, opacities, colors) = (u(3 * n, 0.01, 0.1), u(n, 0.1, 1.0), u(3 * n, 0.0, 1.0));
        let mode = ColorMode::Direct { channels: 3 };
        let scene = Scene::new(&means, &quats, &scales, &opacities, &colors, mode).unwrap();
        let view = [
            1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 4.0, 0.0, 0.0, 0.0, 1.0,
        ];
        let k = [60.0, 0.0, 24.0, 0.0, 60.0, 20.0, 0.0, 0.0, 1.0];
        (scene, Camera::from_matrices(&view, &k, 48, 40).unwrap())
    }

    /// Image and alpha bits of a forward call with these tiles and depth channel.
    fn image_bits(tile_size: u32, with_depth: bool) -> Vec<u32> {
        let (scene, cam) = scene_and_camera();
        let opts = RasterOptions {
            tile_size,
            with_depth,
            ..RasterOptions::default()
        };
        let (out, _) = forward(scene, vec![cam], 48, 40, opts).unwrap();
        out.render
            .iter()
            .chain(&out.alpha)
            .map(|v| v.to_bits())
            .collect()
    }

    #[test]
    fn a_kept_tile_scratch_renders_as_a_fresh_one() {
        // One pool's thread renders tile sizes and channel counts in turn, reusing or
        // replacing the tile scratch it keeps; each is compared with a fresh pool's render.
        let pool = |n| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap()
        };
        let kept = pool(1);
        let settings = [
            (16, false),
            (16, false),
            (32, true),
            (32, true),
            (8, false),
            (16, false),
        ];
        for (tile_size, with_depth) in settings {
            let again = kept.install(|| image_bits(tile_size, with_depth));
            let fresh = pool(1).install(|| image_bits(tile_size, with_depth));
            assert!(
                fresh.iter().any(|&b| b != 0),
                "an empty image proves nothing"
            );
            assert_eq!(again, fresh, "tile {tile_size}, depth {with_depth}");
        }
    }
}
