//! Pinhole cameras as the rasterizer sees them: OpenCV world-to-camera + intrinsics.

use glam::{Mat3, Vec3};

use crate::error::human_bytes;
use crate::{CoreError, CoreResult};

/// Pixels one forward call renders at most, over all its cameras: 2^30, e.g. one image of
/// 32768 x 32768 or 64 of 4096 x 4096. Larger calls are refused before allocating.
pub const MAX_PIXELS: u64 = 1 << 30;

/// Refuses a call whose image buffers cannot be allocated: more than `MAX_PIXELS` pixels,
/// or a size whose byte count overflows. The message gives the size asked for and the
/// memory its per-pixel buffers need (the image's `channels`, alpha, final transmittance
/// and last contributor: 4 bytes each per pixel), before any of it is allocated.
pub fn check_image_size(
    cameras: usize,
    width: u32,
    height: u32,
    channels: usize,
) -> CoreResult<()> {
    let pixels = cameras as u128 * u128::from(width) * u128::from(height);
    let bytes = pixels * (channels as u128 + 3) * 4;
    if pixels > u128::from(MAX_PIXELS) || usize::try_from(bytes).is_err() {
        return Err(CoreError::input(format!(
            "{cameras} image(s) of {width} x {height} pixels is {pixels} pixels, more than \
             the {MAX_PIXELS} one call renders; its image buffers alone would need {}",
            human_bytes(bytes)
        )));
    }
    Ok(())
}

/// One camera: world-to-camera rotation and translation (x right, y down, z forward),
/// focal lengths and principal point in pixels, and the image size.
#[derive(Debug, Clone, Copy)]
pub struct Camera {
    pub rot: Mat3,
    pub trans: Vec3,
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    pub width: u32,
    pub height: u32,
}

impl Camera {
    /// From a row-major 4x4 `viewmat` and a row-major 3x3 `K` (the gsplat layout).
    pub fn from_matrices(viewmat: &[f32], k: &[f32], width: u32, height: u32) -> CoreResult<Self> {
        if viewmat.len() != 16 || k.len() != 9 {
            return Err(CoreError::input("a camera needs 16 viewmat and 9 K values"));
        }
        if !viewmat.iter().chain(k).all(|v| v.is_finite()) {
            return Err(CoreError::input("viewmats and Ks must be finite"));
        }
        let (fx, fy) = (k[0], k[4]);
        if fx <= 0.0 || fy <= 0.0 {
            return Err(CoreError::input(format!(
                "focal lengths must be positive, got fx={fx}, fy={fy}"
            )));
        }
        let v = viewmat;
        Ok(Self {
            rot: Mat3::from_cols(
                Vec3::new(v[0], v[4], v[8]),
                Vec3::new(v[1], v[5], v[9]),
                Vec3::new(v[2], v[6], v[10]),
            ),
            trans: Vec3::new(v[3], v[7], v[11]),
            fx,
            fy,
            cx: k[2],
            cy: k[5],
            width,
            height,
        })
    }

    /// Camera centre in world coordinates (-R^T t); the SH view direction starts here.
    pub fn centre(&self) -> Vec3 {
        -(self.rot.transpose() * self.trans)
    }

    pub fn to_camera(&self, p: Vec3) -> Vec3 {
        self.rot * p + self.trans
    }

    /// Bounds of x/z and y/z used by the EWA Jacobian clamp:
    /// (right, left, down, up) = ((W - cx)/fx + 0.3 tan_fovx, cx/fx + 0.3 tan_fovx, ...).
    pub fn jacobian_limits(&self) -> [f32; 4] {
        let tan_fovx = 0.5 * self.width as f32 / self.fx;
        let tan_fovy = 0.5 * self.height as f32 / self.fy;
        [
            (self.width as f32 - self.cx) / self.fx + 0.3 * tan_fovx,
            self.cx / self.fx + 0.3 * tan_fovx,
            (self.height as f32 - self.cy) / self.fy + 0.3 * tan_fovy,
            self.cy / self.fy + 0.3 * tan_fovy,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_inverts_the_view_transform() {
        // Rotation of 90 degrees about z, then a translation.
        let view = [
            0.0, -1.0, 0.0, 1.0, //
            1.0, 0.0, 0.0, 2.0, //
            0.0, 0.0, 1.0, 3.0, //
            0.0, 0.0, 0.0, 1.0,
        ];
        let k = [100.0, 0.0, 32.0, 0.0, 100.0, 32.0, 0.0, 0.0, 1.0];
        let cam = Camera::from_matrices(&view, &k, 64, 64).unwrap();
        let c = cam.centre();
        assert!(cam.to_camera(c).length() < 1e-6);
        assert_eq!(cam.to_camera(Vec3::X), Vec3::new(1.0, 3.0, 3.0));
    }

    #[test]
    fn rejects_bad_intrinsics() {
        let view = [0.0f32; 16];
        let k = [0.0, 0.0, 32.0, 0.0, 100.0, 32.0, 0.0, 0.0, 1.0];
        assert!(Camera::from_matrices(&view, &k, 64, 64).is_err());
    }

    #[test]
    fn image_sizes_past_the_pixel_limit_are_refused() {
        assert!(check_image_size(64, 4096, 4096, 3).is_ok());
        for (c, w, h) in [
            (65, 4096, 4096),
            (1, 1 << 31, 1 << 31),
            (1, u32::MAX, u32::MAX),
        ] {
            let err = check_image_size(c, w, h, 3).unwrap_err().to_string();
            assert!(err.contains(&format!("{w} x {h}")), "{err}");
            assert!(err.contains("would need"), "{err}");
        }
        let err = check_image_size(1, 1 << 31, 1 << 31, 3)
            .unwrap_err()
            .to_string();
        assert!(err.contains("98304.0 PiB"), "{err}");
    }
}
