//! 3D Gaussian Splatting rasterizer on the CPU: gsplat 1.5 "classic" semantics, forward and
//! backward, rayon-parallel and bit-identical for any thread count.
//!
//! Pipeline per camera (`forward_pass`): `project_batch` (EWA splats, eight Gaussians at a
//! time, built for AVX2 by `project_avx2` where the CPU has it; `project` is the
//! per-Gaussian reference) -> `features` (SH colour / depth)
//! -> `depth_sort` (visible splats front to back, a parallel radix sort) -> `tile_binning`
//! (tile lists) -> `forward_blend` (per-tile compositing).
//! `backward_pass` orders the intersections by splat (`backward_index`), walks the same
//! lists back to front (`backward_blend`) and chains to the 3D parameters
//! (`backward_chain`, through `project_backward_batch`, eight Gaussians at a time).
//!
//! The blending kernels run on groups of eight pixels: AVX2 code in `blend_avx2` where the
//! CPU has it, a scalar version of the same operations otherwise; both give the same bits
//! (tested). Imports run one way, from the drivers down to the shared vocabulary:
//!
//! ```text
//! eval_count                           blending work of a forward state (benchmarks)
//! many_scenes                          many scenes' passes in one call (a group's plants)
//! coverage                             each group's silhouette alone (a leaf's occlusion)
//! forward_pass, backward_pass          whole passes over every camera
//! backward_chain                       per-splat sums -> 3D parameter gradients
//! forward_blend, backward_blend        per-camera blend drivers + scalar kernels
//! blend_avx2                           the AVX2 kernels (unsafe: intrinsics)
//! project_avx2                         project_batch built for AVX2 (unsafe: the call)
//! backward_index                       intersections in splat order
//! tile_walk                            per-tile state, front-to-back / back-to-front walkers
//! tile_geometry                        tile rectangles, footprints, per-tile splat lists
//! tile_binning, depth_sort             tile lists; the depth order they start from
//!                                      (depth_sort unsafe: the parallel scatter)
//! lanes, options, project, ...         lane arithmetic, settings, projection
//! project_backward_batch, batch_lanes  project's backward on eight Gaussians at a time
//!                                      (AVX build; unsafe: the call)
//! ```
//!
//! This file only declares and re-exports; no module imports from it
//! (`tests/raster_layers.rs` checks both rules).
//!
//! State kept between forward and backward (`ForwardState`): a copy of the inputs
//! (O(N)), and per camera the splats and features (O(N)), the tile lists
//! (O(intersections)), and the final transmittance and last-contributor count per pixel
//! (O(pixels)). Nothing per (pixel, splat) pair is stored.

mod background;
mod backward_blend;
mod backward_chain;
mod backward_index;
mod backward_pass;
mod batch_lanes;
#[cfg(target_arch = "x86_64")]
mod blend_avx2;
mod buffers;
pub mod camera;
mod coverage;
mod depth_sort;
mod eval_count;
pub mod features;
mod forward_blend;
mod forward_pass;
#[cfg(all(test, target_arch = "x86_64"))]
mod kernel_tests;
mod lanes;
mod many_scenes;
mod options;
mod prefetch;
pub mod project;
mod project_avx2;
mod project_backward_batch;
mod project_batch;
pub mod scene;
pub mod sh;
#[cfg(test)]
mod test_gaussians;
pub mod tile_binning;
mod tile_geometry;
mod tile_walk;

pub use backward_pass::{backward, GradRequest, Gradients};
pub use camera::Camera;
pub use coverage::{group_coverage, Coverage, LabelMap};
pub use eval_count::{count_evaluations, Evaluations};
pub use forward_blend::{blend_kernel, Blended};
pub use forward_pass::{
    forward, forward_with_background, CameraState, ForwardOutput, ForwardState, Profile,
};
pub use many_scenes::{
    backward_many, forward_many, forward_scene, BackwardJob, ForwardResult, SceneJob,
};
pub use options::{Footprint, RasterOptions, ALPHA_MAX, ALPHA_MIN};
pub use scene::{ColorMode, Scene};
