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
    /// An unsigned integer that orders as the value does (`total_cmp`), at the type's own
    /// width: the kd-tree build partitions on these, so f32 clouds move half the bytes.
    type Key: OrderKey;
    fn to_f64(self) -> f64;
    fn order_key(self) -> Self::Key;
}

/// An order-preserving integer image of a coordinate (see `Coord::Key`).
pub trait OrderKey: Copy + Ord + Send + Sync + 'static {
    /// (key, index) as one integer ordered as the pair.
    type Rank: Copy + Ord;
    fn rank(self, id: u32) -> Self::Rank;
    /// The coordinate the key came from, as f64 (exact: f32 widens without rounding).
    fn value(self) -> f64;
}

impl Coord for f32 {
    type Key = u32;
    #[inline]
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
    #[inline]
    fn order_key(self) -> u32 {
        // `total_cmp`'s transform (negatives: magnitude bits flipped), then the sign bit
        // flipped so the signed order becomes the unsigned one.
        let b = self.to_bits() as i32;
        ((b ^ (((b >> 31) as u32) >> 1) as i32) as u32) ^ (1 << 31)
    }
}

impl OrderKey for u32 {
    type Rank = u64;
    #[inline]
    fn rank(self, id: u32) -> u64 {
        (u64::from(self) << 32) | u64::from(id)
    }
    #[inline]
    fn value(self) -> f64 {
        let s = (self ^ (1 << 31)) as i32;
        f64::from(f32::from_bits(
            (s ^ (((s >> 31) as u32) >> 1) as i32) as u32,
        ))
    }
}

impl Coord for f64 {
    type Key = u64;
    #[inline]
    fn to_f64(self) -> f64 {
        self
    }
    #[inline]
    fn order_key(self) -> u64 {
        let b = self.to_bits() as i64;
        ((b ^ (((b >> 63) as u64) >> 1) as i64) as u64) ^ (1 << 63)
    }
}

impl OrderKey for u64 {
    type Rank = u128;
    #[inline]
    fn rank(self, id: u32) -> u128 {
        (u128::from(self) << 32) | u128::from(id)
    }
    #[inline]
    fn value(self) -> f64 {
        let s = (self ^ (1 << 63)) as i64;
        f64::from_bits((s ^ (((s >> 63) as u64) >> 1) as i64) as u64)
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Order keys sort as `total_cmp` sorts the values (signed zeros, subnormals and
    /// extremes included) and give back the exact value.
    #[test]
    fn order_keys_order_as_the_values() {
        let mut v32 = vec![
            0.0f32,
            -0.0,
            1.0,
            -1.0,
            f32::MIN,
            f32::MAX,
            f32::MIN_POSITIVE,
            -f32::MIN_POSITIVE,
            1e-45,
            -1e-45,
            0.1,
            -0.1,
            3.5,
            -3.5,
        ];
        v32.sort_by(f32::total_cmp);
        let k32: Vec<u32> = v32.iter().map(|v| v.order_key()).collect();
        assert!(k32.windows(2).all(|w| w[0] < w[1]));
        for (v, k) in v32.iter().zip(&k32) {
            assert_eq!(k.value().to_bits(), f64::from(*v).to_bits());
        }
        let mut v64: Vec<f64> = v32.iter().map(|&v| f64::from(v)).collect();
        v64.extend([f64::MIN, f64::MAX, 5e-324, -5e-324, 0.1, -0.1]);
        v64.sort_by(f64::total_cmp);
        let k64: Vec<u64> = v64.iter().map(|v| v.order_key()).collect();
        assert!(k64.windows(2).all(|w| w[0] < w[1]));
        for (v, k) in v64.iter().zip(&k64) {
            assert_eq!(k.value().to_bits(), v.to_bits());
        }
    }
}
