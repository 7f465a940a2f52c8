//! k nearest neighbours of every point of a cloud (the point itself excluded).

use rayon::prelude::*;

use super::nearest::map_knn_distances;
use super::{check_points, Coord, KdTree};
use crate::error::human_bytes;
use crate::memory::try_filled;
use crate::{CoreError, CoreResult};

/// n x k at most for one call (2^31): the neighbour pairs it finds, and so its work and,
/// for `knn`, its output (12 bytes a pair: 24 GiB at the limit). Larger calls are refused
/// before anything is allocated.
pub const MAX_NEIGHBOUR_PAIRS: usize = 1 << 31;

pub(super) fn check_k(n: usize, k: usize, what: &str) -> CoreResult<()> {
    if k == 0 {
        return Err(CoreError::input(format!("{what} must be at least 1")));
    }
    if k >= n {
        return Err(CoreError::input(format!(
            "the cloud has {n} points: too few for {what}={k} neighbours (need at least {})",
            k + 1
        )));
    }
    let pairs = n as u128 * k as u128;
    if pairs > MAX_NEIGHBOUR_PAIRS as u128 {
        return Err(CoreError::input(format!(
            "{what}={k} neighbours of each of {n} points is {pairs} pairs, more than the \
             {MAX_NEIGHBOUR_PAIRS} one call handles (the indices and distances alone would \
             take {})",
            human_bytes(pairs * 12)
        )));
    }
    Ok(())
}

/// The k nearest other points of every point: (indices [n*k], distances [n*k]), row-major,
/// nearest first. Ties at equal distance go to the smaller index among the candidates the
/// search visits; the result never depends on the thread count.
pub fn knn<T: Coord>(points: &[T], k: usize) -> CoreResult<(Vec<i64>, Vec<f32>)> {
    let n = check_points(points)?;
    check_k(n, k, "k")?;
    let mut indices = try_filled(n * k, 0i64)?;
    let mut distances = try_filled(n * k, 0f32)?;
    let tree = KdTree::build(points);
    let rows = tree.map_knn(k, |_, nb| {
        let ids: Vec<i64> = nb.indices().iter().map(|&i| i64::from(i)).collect();
        let d: Vec<f32> = nb
            .squared_distances()
            .iter()
            .map(|&d| d.sqrt() as f32)
            .collect();
        (ids, d)
    });
    let inv = tree.positions();
    indices
        .par_chunks_mut(k)
        .zip(distances.par_chunks_mut(k))
        .zip(inv.par_iter())
        .for_each(|((ids, d), &pos)| {
            let (src_ids, src_d) = &rows[pos as usize];
            ids.copy_from_slice(src_ids);
            d.copy_from_slice(src_d);
        });
    Ok((indices, distances))
}

/// Mean distance from every point to its k nearest other points (computed in f64).
/// This is the isotropic scale PlantDreamer initialises each Gaussian with (k = 3).
pub fn knn_mean_distance<T: Coord>(points: &[T], k: usize) -> CoreResult<Vec<f32>> {
    let n = check_points(points)?;
    check_k(n, k, "k")?;
    let tree = KdTree::build(points);
    let means = map_knn_distances(&tree, k, |_, d2| {
        d2.iter().map(|d| d.sqrt()).sum::<f64>() / k as f64
    });
    let inv = tree.positions();
    Ok(inv
        .par_iter()
        .map(|&pos| means[pos as usize] as f32)
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::threads::with_threads;

    fn cloud(n: usize) -> Vec<f32> {
        (0..3 * n)
            .map(|i| ((i as f32) * 0.7131).sin() * 3.0 + (i % 7) as f32 * 0.01)
            .collect()
    }

    #[test]
    fn knn_matches_brute_force_distances() {
        let pts = cloud(500);
        let (ids, d) = knn(&pts, 5).unwrap();
        for q in 0..500 {
            let mut all: Vec<f64> = (0..500)
                .filter(|&j| j != q)
                .map(|j| {
                    (0..3)
                        .map(|a| (f64::from(pts[3 * q + a]) - f64::from(pts[3 * j + a])).powi(2))
                        .sum::<f64>()
                        .sqrt()
                })
                .collect();
            all.sort_by(f64::total_cmp);
            for c in 0..5 {
                assert_eq!(d[q * 5 + c], all[c] as f32);
                assert_ne!(ids[q * 5 + c], q as i64);
            }
        }
    }

    #[test]
    fn results_do_not_depend_on_threads() {
        let pts = cloud(20_000);
        let one = with_threads(Some(1), || knn(&pts, 8)).unwrap();
        let two = with_threads(Some(2), || knn(&pts, 8)).unwrap();
        assert_eq!(one, two);
        let m1 = with_threads(Some(1), || knn_mean_distance(&pts, 3)).unwrap();
        let m2 = with_threads(Some(2), || knn_mean_distance(&pts, 3)).unwrap();
        assert_eq!(m1, m2);
    }

    #[test]
    fn k_close_to_n_matches_brute_force() {
        // Every other point but one: the heap layout of the neighbour list.
        let pts = cloud(300);
        let (ids, d) = knn(&pts, 298).unwrap();
        for q in (0..300).step_by(37) {
            let mut all: Vec<(f64, i64)> = (0..300)
                .filter(|&j| j != q)
                .map(|j| {
                    let d2: f64 = (0..3)
                        .map(|a| (f64::from(pts[3 * q + a]) - f64::from(pts[3 * j + a])).powi(2))
                        .sum();
                    (d2, j as i64)
                })
                .collect();
            all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            for c in 0..298 {
                assert_eq!(ids[q * 298 + c], all[c].1, "query {q} rank {c}");
                assert_eq!(d[q * 298 + c], all[c].0.sqrt() as f32);
            }
        }
    }

    #[test]
    fn bad_k_is_an_input_error() {
        let pts = cloud(4);
        assert!(matches!(knn(&pts, 4), Err(CoreError::Input(_))));
        assert!(matches!(knn(&pts, 0), Err(CoreError::Input(_))));
        assert!(knn(&pts, 3).is_ok());
        assert!(matches!(knn::<f32>(&[], 1), Err(CoreError::Input(_))));
        let err = check_k(1 << 20, 1 << 12, "k").unwrap_err().to_string();
        assert!(
            err.contains("4294967296 pairs") && err.contains("48.0 GiB"),
            "{err}"
        );
        assert!(check_k(1 << 20, 1 << 11, "k").is_ok());
        assert!(matches!(
            knn(&[0.0, f32::NAN, 0.0, 1.0, 1.0, 1.0], 1),
            Err(CoreError::Input(_))
        ));
    }
}
