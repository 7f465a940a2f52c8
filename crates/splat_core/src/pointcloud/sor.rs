//! Statistical outlier removal with Open3D 0.20's legacy semantics.
//!
//! Open3D (`PointCloud::RemoveStatisticalOutliers`): each point's kNN includes the point
//! itself (distance 0), its score is the mean of the k distances summed nearest first;
//! the cloud mean is the sum of the positive scores divided by the number of points,
//! the deviation is sqrt(sum over positive scores of (score - mean)^2 / (n - 1)); a point is
//! kept iff 0 < score < mean + std_ratio * std. Points with k - 1 exact duplicates score 0
//! and are dropped, as in Open3D. Same f64 operations in the same order, so the kept set is
//! the same as Open3D's.

use rayon::prelude::*;

use super::knn::check_k;
use super::nearest::{map_knn_distances, NETWORK_MAX};
use super::{check_points, Coord, KdTree};
use crate::{CoreError, CoreResult};

/// Per-point score: mean distance to the `nb_neighbors` nearest points, the point included.
pub fn statistical_outlier_scores<T: Coord>(
    points: &[T],
    nb_neighbors: usize,
) -> CoreResult<Vec<f64>> {
    let n = check_points(points)?;
    if nb_neighbors > n {
        return Err(CoreError::input(format!(
            "the cloud has {n} points, fewer than nb_neighbors={nb_neighbors}"
        )));
    }
    if nb_neighbors > 1 {
        check_k(n, nb_neighbors - 1, "nb_neighbors - 1")?;
    } else if nb_neighbors == 0 {
        return Err(CoreError::input("nb_neighbors must be at least 1"));
    }
    let others = nb_neighbors - 1;
    let tree = KdTree::build(points);
    let scores = if others == 0 {
        vec![0.0; n]
    } else {
        map_knn_distances(&tree, others, |_, d2s| {
            // Open3D: the point itself first (sqrt(0) = 0), then the others nearest first.
            // The roots first, as one vectorisable loop, then the sum in that order.
            let mut sum = 0.0f64;
            for chunk in d2s.chunks(NETWORK_MAX) {
                let mut roots = [0.0f64; NETWORK_MAX];
                for (r, &d2) in roots.iter_mut().zip(chunk) {
                    *r = d2.sqrt();
                }
                for &r in &roots[..chunk.len()] {
                    sum += r;
                }
            }
            sum / nb_neighbors as f64
        })
    };
    let inv = tree.positions();
    Ok(inv.par_iter().map(|&pos| scores[pos as usize]).collect())
}

/// Indices (ascending) of the points Open3D 0.20's `remove_statistical_outlier` keeps.
pub fn remove_statistical_outliers<T: Coord>(
    points: &[T],
    nb_neighbors: usize,
    std_ratio: f64,
) -> CoreResult<Vec<i64>> {
    if !(std_ratio.is_finite() && std_ratio > 0.0) {
        return Err(CoreError::input(format!(
            "std_ratio must be a positive number, got {std_ratio}"
        )));
    }
    let scores = statistical_outlier_scores(points, nb_neighbors)?;
    let n = scores.len();
    if n < 2 {
        // One point: its score is 0, which Open3D never keeps (and n - 1 = 0).
        return Ok(Vec::new());
    }
    let mut sum = 0.0f64;
    for &s in &scores {
        if s > 0.0 {
            sum += s;
        }
    }
    let mean = sum / n as f64;
    let mut sq_sum = 0.0f64;
    for &s in &scores {
        sq_sum += if s > 0.0 {
            (s - mean) * (s - mean)
        } else {
            0.0
        };
    }
    let std = (sq_sum / (n - 1) as f64).sqrt();
    let threshold = mean + std_ratio * std;
    Ok(scores
        .iter()
        .enumerate()
        .filter(|(_, &s)| s > 0.0 && s < threshold)
        .map(|(i, _)| i as i64)
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng::Lcg;
    use crate::threads::with_threads;

    /// Plain O(n^2) float64 reference of the same semantics.
    fn reference(pts: &[f32], k: usize, ratio: f64) -> Vec<i64> {
        let n = pts.len() / 3;
        let scores: Vec<f64> = (0..n)
            .map(|q| {
                let mut d: Vec<f64> = (0..n)
                    .map(|j| {
                        (0..3)
                            .map(|a| {
                                (f64::from(pts[3 * q + a]) - f64::from(pts[3 * j + a])).powi(2)
                            })
                            .sum::<f64>()
                            .sqrt()
                    })
                    .collect();
                d.sort_by(f64::total_cmp);
                d[..k].iter().sum::<f64>() / k as f64
            })
            .collect();
        let mean = scores.iter().filter(|&&s| s > 0.0).sum::<f64>() / n as f64;
        let var = scores
            .iter()
            .filter(|&&s| s > 0.0)
            .map(|s| (s - mean).powi(2))
            .sum::<f64>()
            / (n - 1) as f64;
        let thr = mean + ratio * var.sqrt();
        (0..n as i64)
            .filter(|&i| scores[i as usize] > 0.0 && scores[i as usize] < thr)
            .collect()
    }

    fn noisy_cloud(n: usize) -> Vec<f32> {
        let mut rng = Lcg::new(7);
        let mut rnd = move || rng.uniform();
        let mut v = Vec::new();
        for i in 0..n {
            let scale = if i % 50 == 0 { 5.0 } else { 1.0 };
            v.extend([rnd() * scale, rnd() * scale, rnd() * 0.1 * scale]);
        }
        v
    }

    #[test]
    fn kept_set_matches_reference() {
        let pts = noisy_cloud(1500);
        for (k, ratio) in [(20, 2.0), (5, 1.0), (2, 3.0)] {
            let got = remove_statistical_outliers(&pts, k, ratio).unwrap();
            assert_eq!(got, reference(&pts, k, ratio), "k={k} ratio={ratio}");
            assert!(got.len() < 1500 && got.len() > 1000);
        }
    }

    #[test]
    fn duplicates_score_zero_and_are_dropped() {
        let mut pts = noisy_cloud(300);
        pts.extend([0.25f32, 0.25, 0.25].repeat(40));
        let kept = remove_statistical_outliers(&pts, 20, 2.0).unwrap();
        assert!(kept.iter().all(|&i| i < 300));
        assert_eq!(kept, reference(&pts, 20, 2.0));
    }

    #[test]
    fn thread_count_does_not_matter() {
        let pts = noisy_cloud(30_000);
        let a = with_threads(Some(1), || remove_statistical_outliers(&pts, 20, 2.0)).unwrap();
        let b = with_threads(Some(2), || remove_statistical_outliers(&pts, 20, 2.0)).unwrap();
        assert_eq!(a, b);
    }

    #[test]
    fn collinear_identical_and_non_finite_clouds() {
        // Collinear, with a stretch of wider spacing: equal distances everywhere.
        let mut line: Vec<f32> = Vec::new();
        for i in 0..400 {
            let x = if i < 350 {
                i as f32 * 0.5
            } else {
                175.0 + (i - 350) as f32 * 3.0
            };
            line.extend([x, 2.0 * x, -x]);
        }
        assert_eq!(
            remove_statistical_outliers(&line, 20, 1.0).unwrap(),
            reference(&line, 20, 1.0)
        );
        // All points identical: every score is 0, nothing is kept (as Open3D).
        let same = [0.25f32, -1.0, 3.0].repeat(500);
        assert_eq!(
            remove_statistical_outliers(&same, 20, 2.0).unwrap(),
            Vec::<i64>::new()
        );
        let mut bad = noisy_cloud(50);
        bad[31] = f32::NAN;
        assert!(matches!(
            remove_statistical_outliers(&bad, 5, 2.0),
            Err(CoreError::Input(_))
        ));
        bad[31] = f32::INFINITY;
        assert!(matches!(
            statistical_outlier_scores(&bad, 5),
            Err(CoreError::Input(_))
        ));
    }

    #[test]
    fn degenerate_inputs() {
        let pts = noisy_cloud(10);
        assert!(matches!(
            remove_statistical_outliers(&pts, 11, 2.0),
            Err(CoreError::Input(_))
        ));
        assert!(matches!(
            remove_statistical_outliers(&pts, 0, 2.0),
            Err(CoreError::Input(_))
        ));
        assert!(matches!(
            remove_statistical_outliers(&pts, 5, 0.0),
            Err(CoreError::Input(_))
        ));
        assert!(matches!(
            remove_statistical_outliers(&pts, 5, f64::NAN),
            Err(CoreError::Input(_))
        ));
        assert_eq!(
            remove_statistical_outliers(&pts, 1, 2.0).unwrap(),
            Vec::<i64>::new()
        );
        assert_eq!(
            remove_statistical_outliers(&pts[..3], 1, 2.0).unwrap(),
            Vec::<i64>::new()
        );
        assert_eq!(
            remove_statistical_outliers(&pts, 10, 2.0).unwrap(),
            reference(&pts, 10, 2.0)
        );
    }
}
