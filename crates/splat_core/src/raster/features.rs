//! Per-splat feature vectors blended into the image: colour (direct or from SH, seen from
//! the camera centre) and optionally the camera-space depth as the last channel.

use rayon::prelude::*;

use super::buffers::filled;
use super::camera::Camera;
use super::project::Splat;
use super::scene::{ColorMode, Scene};
use super::sh;
use crate::CoreResult;

/// Features [N, ch]; zero rows for culled splats (never read).
pub fn compute(
    scene: &Scene,
    cam: &Camera,
    splats: &[Splat],
    with_depth: bool,
) -> CoreResult<Vec<f32>> {
    let cc = scene.color_channels();
    let ch = cc + with_depth as usize;
    let centre = cam.centre();
    let mut out = filled(scene.n * ch, 0.0f32)?;
    out.par_chunks_mut(ch)
        .zip(splats.par_iter())
        .enumerate()
        .for_each(|(i, (f, s))| {
            if !s.visible() {
                return;
            }
            match scene.color_mode {
                ColorMode::None => {}
                // A fixed width for RGB: a copy of a run-time length is a memcpy call.
                ColorMode::Direct { channels: 3 } => {
                    let row: [f32; 3] = scene.colors[3 * i..3 * i + 3].try_into().unwrap();
                    f[..3].copy_from_slice(&row);
                }
                ColorMode::Direct { .. } => f[..cc].copy_from_slice(scene.color_row(i)),
                ColorMode::Sh { degree, .. } => {
                    let dir = scene.gaussian(i).mean - centre;
                    let v = sh::eval(degree, scene.color_row(i), dir);
                    for c in 0..3 {
                        f[c] = (v[c] + 0.5).max(0.0);
                    }
                }
            }
            if with_depth {
                f[cc] = s.depth;
            }
        });
    Ok(out)
}
