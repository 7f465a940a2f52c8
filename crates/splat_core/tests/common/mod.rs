//! Shared helpers of the rasterizer integration tests.
#![allow(dead_code)]

use splat_core::raster::{Camera, ColorMode, RasterOptions, Scene};

/// xorshift64*: a tiny deterministic generator (tests must not depend on a crate's stream).
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.uniform()
    }

    pub fn normal(&mut self) -> f32 {
        let (u, v) = (self.uniform().max(1e-7), self.uniform());
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f32::consts::PI * v).cos()
    }

    pub fn pick<T: Copy>(&mut self, xs: &[T]) -> T {
        xs[(self.next_u64() % xs.len() as u64) as usize]
    }
}

/// A camera at (0, 0, -dist) looking along +z (identity rotation), square image.
pub fn axis_camera(size: u32, focal: f32, dist: f32) -> Camera {
    let view = [
        1.0, 0.0, 0.0, 0.0, //
        0.0, 1.0, 0.0, 0.0, //
        0.0, 0.0, 1.0, dist, //
        0.0, 0.0, 0.0, 1.0,
    ];
    let half = size as f32 / 2.0;
    let k = [focal, 0.0, half, 0.0, focal, half, 0.0, 0.0, 1.0];
    Camera::from_matrices(&view, &k, size, size).unwrap()
}

/// Flat parameter vectors of a scene, for perturbing one value at a time.
#[derive(Clone)]
pub struct Params {
    pub means: Vec<f32>,
    pub quats: Vec<f32>,
    pub scales: Vec<f32>,
    pub opacities: Vec<f32>,
    pub colors: Vec<f32>,
    pub mode: ColorMode,
}

impl Params {
    pub fn scene(&self) -> Scene {
        Scene::new(
            &self.means,
            &self.quats,
            &self.scales,
            &self.opacities,
            &self.colors,
            self.mode,
        )
        .unwrap()
    }

    pub fn group(&mut self, g: usize) -> &mut Vec<f32> {
        match g {
            0 => &mut self.means,
            1 => &mut self.quats,
            2 => &mut self.scales,
            3 => &mut self.opacities,
            _ => &mut self.colors,
        }
    }
}

pub fn default_opts() -> RasterOptions {
    RasterOptions::default()
}
