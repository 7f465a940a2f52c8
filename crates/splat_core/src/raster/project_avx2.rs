//! `project_batch::project_all` compiled for AVX2 where the CPU has it: the same lane
//! code, eight f32 lanes per instruction instead of four (SSE2, the x86-64 baseline). The
//! operations are IEEE and the compiler contracts none into fused multiply-adds, so both
//! builds give the same bits (`tests`). Only unsafe code here: the call into the
//! `#[target_feature]` function after `is_x86_feature_detected!("avx2")`.
#![allow(unsafe_code)]

use super::camera::Camera;
use super::options::RasterOptions;
use super::project::Splat;
use super::project_batch::{self, Block};
use super::scene::Scene;
use crate::CoreResult;

/// Projects every Gaussian of the scene for one camera; see `project_batch::project_all`.
pub fn project_all(scene: &Scene, cam: &Camera, opts: &RasterOptions) -> CoreResult<Vec<Splat>> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2 (checked above).
        return project_batch::project_all_by(scene, cam, opts, |b| unsafe { run_avx2(b) });
    }
    project_batch::project_all(scene, cam, opts)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn run_avx2(block: Block) {
    block.run()
}
