//! Point-cloud filters: kNN, statistical outlier removal, voxel grid downsampling.
//!
//! Points are flat `[x0, y0, z0, x1, ...]` slices of f32 or f64; all distance math runs in
//! f64, as Open3D does (its legacy point cloud stores `Eigen::Vector3d`), so kept sets and
//! voxel means match Open3D's bit for bit on the same input.
//!
//! `kdtree` builds the tree and finds neighbours with their indices (`knn`); `nearest`
//! finds the distances alone (SOR scores, mean kNN distance) over the same tree with a
//! cheaper neighbour list, and `nearest_avx2` is its AVX2 instance.

mod kdtree;
mod knn;
mod nearest;
#[cfg(target_arch = "x86_64")]
mod nearest_avx2;
mod sor;
mod voxel;

pub use kdtree::KdTree;
pub use knn::{knn, knn_mean_distance, MAX_NEIGHBOUR_PAIRS};
pub use sor::{remove_statistical_outliers, statistical_outlier_scores};
pub use voxel::{downsample_to_count, voxel_count, voxel_downsample, CountDownsample, VoxelOutput};

use crate::{CoreError, CoreResult};

/// A coordinate type the filters accept.
pub trait Coord: Copy + Send + Sync + 'static {
    fn to_f64(self) -> f64;
}

impl Coord for f32 {
    #[inline]
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
}

impl Coord for f64 {
    #[inline]
    fn to_f64(self) -> f64 {
        self
    }
}

/// Checks a flat xyz slice: whole rows, at least one point, indexable by u32, all finite.
/// Returns the number of points.
pub fn check_points<T: Coord>(points: &[T]) -> CoreResult<usize> {
    // `is_multiple_of` needs Rust 1.87; the workspace supports 1.80.
    #[allow(clippy::manual_is_multiple_of)]
    if points.len() % 3 != 0 {
        return Err(CoreError::input(format!(
            "points: expected rows of 3 coordinates, got {} values",
            points.len()
        )));
    }
    let n = points.len() / 3;
    if n == 0 {
        return Err(CoreError::input("points: the cloud is empty"));
    }
    if n > u32::MAX as usize {
        return Err(CoreError::input(format!(
            "points: {n} points is more than the supported {}",
            u32::MAX
        )));
    }
    let bad = points.iter().filter(|v| !v.to_f64().is_finite()).count();
    if bad > 0 {
        let first = points
            .iter()
            .position(|v| !v.to_f64().is_finite())
            .unwrap_or(0)
            / 3;
        return Err(CoreError::input(format!(
            "points: {bad} non-finite coordinates (NaN or Inf), the first in point {first}; \
             drop or repair those points first"
        )));
    }
    Ok(n)
}

#[inline]
fn point<T: Coord>(points: &[T], i: usize) -> [f64; 3] {
    [
        points[3 * i].to_f64(),
        points[3 * i + 1].to_f64(),
        points[3 * i + 2].to_f64(),
    ]
}
