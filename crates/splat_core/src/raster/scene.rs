//! The Gaussians being rendered, owned (the backward pass needs them again).

use glam::Vec3;

use super::project::Gaussian3;
use super::sh;
use crate::error::check_len;
use crate::{CoreError, CoreResult};

/// How `colors` is interpreted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColorMode {
    /// No colour channels (depth-only rendering).
    None,
    /// `channels` values per Gaussian, blended as they are.
    Direct { channels: usize },
    /// SH coefficients [K, 3] per Gaussian, evaluated to `degree` (K >= (degree + 1)^2);
    /// colour = max(SH(dir) + 0.5, 0).
    Sh { degree: usize, bases: usize },
}

/// N Gaussians in activated form: means [N, 3], quats [N, 4] (w, x, y, z), scales [N, 3],
/// opacities [N], colours per `color_mode`.
#[derive(Debug, Clone)]
pub struct Scene {
    pub n: usize,
    pub means: Vec<f32>,
    pub quats: Vec<f32>,
    pub scales: Vec<f32>,
    pub opacities: Vec<f32>,
    pub colors: Vec<f32>,
    pub color_mode: ColorMode,
}

impl Scene {
    /// Copies and checks the arrays' lengths.
    pub fn new(
        means: &[f32],
        quats: &[f32],
        scales: &[f32],
        opacities: &[f32],
        colors: &[f32],
        color_mode: ColorMode,
    ) -> CoreResult<Self> {
        Self::from_vecs(
            means.to_vec(),
            quats.to_vec(),
            scales.to_vec(),
            opacities.to_vec(),
            colors.to_vec(),
            color_mode,
        )
    }

    /// Takes the arrays (no copy) and checks their lengths.
    pub fn from_vecs(
        means: Vec<f32>,
        quats: Vec<f32>,
        scales: Vec<f32>,
        opacities: Vec<f32>,
        colors: Vec<f32>,
        color_mode: ColorMode,
    ) -> CoreResult<Self> {
        if !means.len().is_multiple_of(3) {
            return Err(CoreError::input("means must hold N x 3 values"));
        }
        let n = means.len() / 3;
        check_len("quats", &quats, n, 4)?;
        check_len("scales", &scales, n, 3)?;
        check_len("opacities", &opacities, n, 1)?;
        match color_mode {
            ColorMode::None => {}
            ColorMode::Direct { channels } => {
                if channels == 0 {
                    return Err(CoreError::input("colors need at least one channel"));
                }
                check_len("colors", &colors, n, channels)?;
            }
            ColorMode::Sh { degree, bases } => {
                if degree > 3 {
                    return Err(CoreError::input(format!(
                        "sh_degree must be 0..=3, got {degree}"
                    )));
                }
                if bases < sh::num_bases(degree) {
                    return Err(CoreError::input(format!(
                        "SH degree {degree} needs {} coefficients per Gaussian, got {bases}",
                        sh::num_bases(degree)
                    )));
                }
                check_len("colors", &colors, n, bases * 3)?;
            }
        }
        Ok(Self {
            n,
            means,
            quats,
            scales,
            opacities,
            colors,
            color_mode,
        })
    }

    pub fn gaussian(&self, i: usize) -> Gaussian3 {
        let m = &self.means[3 * i..3 * i + 3];
        let s = &self.scales[3 * i..3 * i + 3];
        let q = &self.quats[4 * i..4 * i + 4];
        Gaussian3 {
            mean: Vec3::new(m[0], m[1], m[2]),
            quat: [q[0], q[1], q[2], q[3]],
            scale: Vec3::new(s[0], s[1], s[2]),
            opacity: self.opacities[i],
        }
    }

    /// Colour channels rendered per pixel.
    pub fn color_channels(&self) -> usize {
        match self.color_mode {
            ColorMode::None => 0,
            ColorMode::Direct { channels } => channels,
            ColorMode::Sh { .. } => 3,
        }
    }

    /// Values of `colors` per Gaussian.
    pub fn color_width(&self) -> usize {
        match self.color_mode {
            ColorMode::None => 0,
            ColorMode::Direct { channels } => channels,
            ColorMode::Sh { bases, .. } => 3 * bases,
        }
    }

    pub fn color_row(&self, i: usize) -> &[f32] {
        let w = self.color_width();
        &self.colors[i * w..(i + 1) * w]
    }
}
