//! The projection tests' Gaussians: random ones pushed by each test, plus the degenerate
//! cases the culling rules are about, shared so every batch path is checked on the same set.

use super::scene::{ColorMode, Scene};

/// (mean, quaternion, scales, opacity) of one Gaussian.
pub(crate) type Gaussian = ([f32; 3], [f32; 4], [f32; 3], f32);

/// At the camera, zero quaternion, zero scales, huge scales, NaN mean, infinite quaternion.
pub(crate) const DEGENERATE: [Gaussian; 6] = [
    ([0.0, 0.0, -4.0], [1.0, 0.0, 0.0, 0.0], [0.1; 3], 0.9),
    ([0.0, 0.0, 0.0], [0.0; 4], [0.1; 3], 0.9),
    ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0; 3], 0.9),
    ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [1e30; 3], 0.9),
    ([f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.1; 3], 0.9),
    (
        [0.0, 0.0, 0.0],
        [1.0, f32::INFINITY, 0.0, 0.0],
        [0.1; 3],
        0.9,
    ),
];

/// Far below a pixel: kept only by the 2D dilation.
pub(crate) const SUB_PIXEL: Gaussian = ([0.0, 0.0, 0.0], [2.0, 0.0, 0.0, 0.0], [1e-7; 3], 1.0);

/// Gaussians collected as the flat arrays `Scene::new` takes.
#[derive(Default)]
pub(crate) struct GaussianLists {
    means: Vec<f32>,
    quats: Vec<f32>,
    scales: Vec<f32>,
    opacities: Vec<f32>,
}

impl GaussianLists {
    pub fn push(&mut self, (mean, quat, scales, opacity): Gaussian) {
        self.means.extend(mean);
        self.quats.extend(quat);
        self.scales.extend(scales);
        self.opacities.push(opacity);
    }

    pub fn len(&self) -> usize {
        self.opacities.len()
    }

    /// A direct-colour RGB scene with these Gaussians.
    pub fn scene(&self, colors: &[f32]) -> Scene {
        let (m, q, s, o) = (&self.means, &self.quats, &self.scales, &self.opacities);
        Scene::new(m, q, s, o, colors, ColorMode::Direct { channels: 3 }).unwrap()
    }
}
