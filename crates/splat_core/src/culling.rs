//! Large-Gaussian culling statistics (PlantDreamer, Sec. 3.3).
//!
//! V = sqrt(sum_i exp(s_i)^2) over the three log-scales s_i; a Gaussian is culled when
//! V > mean(V) + C * std(V). The released code applied `exp` to already-activated scales
//! (exp twice); this follows the paper's formula on log-scales.

use rayon::prelude::*;

use crate::error::check_len;
use crate::{CoreError, CoreResult};

/// Summary of one culling decision, reported in run logs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CullStats {
    pub mean: f64,
    pub std: f64,
    pub threshold: f64,
    pub culled: usize,
}

/// Linear-scale "volume" V of each Gaussian, in f64 (exp of large log-scales overflows f32).
pub fn volumes(log_scales: &[f32]) -> Vec<f64> {
    log_scales
        .par_chunks_exact(3)
        .map(|s| {
            let (a, b, c) = (
                (s[0] as f64).exp(),
                (s[1] as f64).exp(),
                (s[2] as f64).exp(),
            );
            (a * a + b * b + c * c).sqrt()
        })
        .collect()
}

/// Which Gaussians to cull. Non-finite volumes (NaN or overflowing scales) are always culled
/// and left out of the statistics so one broken Gaussian cannot hide the others.
/// `std` uses Bessel's correction (n - 1), matching `torch.std`'s default.
pub fn large_gaussians(log_scales: &[f32], c: f64) -> CoreResult<(Vec<bool>, CullStats)> {
    if !c.is_finite() {
        return Err(CoreError::input(format!(
            "culling threshold must be finite, got {c}"
        )));
    }
    let n = log_scales.len() / 3;
    check_len("log_scales", log_scales, n, 3)?;
    let v = volumes(log_scales);
    // Fixed chunking and a sequential reduction keep the sums thread-count independent.
    let (count, sum) = v
        .par_chunks(4096)
        .map(|ch| {
            ch.iter()
                .filter(|x| x.is_finite())
                .fold((0usize, 0.0f64), |(k, s), x| (k + 1, s + x))
        })
        .collect::<Vec<_>>()
        .into_iter()
        .fold((0usize, 0.0f64), |(k, s), (k2, s2)| (k + k2, s + s2));
    let mean = if count > 0 { sum / count as f64 } else { 0.0 };
    let sq: f64 = v
        .par_chunks(4096)
        .map(|ch| {
            ch.iter()
                .filter(|x| x.is_finite())
                .map(|x| (x - mean) * (x - mean))
                .sum::<f64>()
        })
        .collect::<Vec<_>>()
        .into_iter()
        .sum();
    let std = if count > 1 {
        (sq / (count - 1) as f64).sqrt()
    } else {
        0.0
    };
    let threshold = mean + c * std;
    let mask: Vec<bool> = v.iter().map(|x| !x.is_finite() || *x > threshold).collect();
    let culled = mask.iter().filter(|m| **m).count();
    Ok((
        mask,
        CullStats {
            mean,
            std,
            threshold,
            culled,
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::threads::with_threads;

    fn iso(log_s: f32, n: usize) -> Vec<f32> {
        vec![log_s; 3 * n]
    }

    #[test]
    fn planted_giants_are_exactly_the_culled_ones() {
        let mut s = Vec::new();
        for i in 0..1000 {
            let x = -4.0 + 0.001 * (i % 17) as f32;
            s.extend([x, x - 0.1, x + 0.05]);
        }
        for &i in &[3usize, 500, 999] {
            s[3 * i] = 1.0; // e^1 = 2.7 >> e^-4 = 0.018
        }
        let (mask, stats) = large_gaussians(&s, 3.0).unwrap();
        let culled: Vec<usize> = (0..1000).filter(|&i| mask[i]).collect();
        assert_eq!(culled, vec![3, 500, 999]);
        assert_eq!(stats.culled, 3);
    }

    #[test]
    fn volume_is_the_norm_of_linear_scales() {
        let v = volumes(&[0.0, 0.0, 0.0, 2f32.ln(), 0.0, f32::NEG_INFINITY]);
        assert!((v[0] - 3f64.sqrt()).abs() < 1e-12);
        assert!((v[1] - 5f64.sqrt()).abs() < 1e-6);
    }

    #[test]
    fn identical_gaussians_are_kept() {
        let (mask, stats) = large_gaussians(&iso(-3.0, 100), 3.0).unwrap();
        assert!(mask.iter().all(|m| !m));
        assert!(stats.std < 1e-12);
    }

    #[test]
    fn non_finite_is_culled_and_ignored_by_stats() {
        let mut s = iso(-3.0, 10);
        s[0] = f32::NAN;
        s[4] = 1e30; // exp overflows f64 -> inf
        let (mask, stats) = large_gaussians(&s, 3.0).unwrap();
        assert!(mask[0] && mask[1]);
        assert_eq!(stats.culled, 2);
        assert!(stats.mean.is_finite() && stats.std < 1e-12);
    }

    #[test]
    fn empty_and_bad_inputs() {
        let (mask, stats) = large_gaussians(&[], 3.0).unwrap();
        assert!(mask.is_empty() && stats.culled == 0);
        assert!(large_gaussians(&[0.0; 4], 3.0).is_err());
        assert!(large_gaussians(&[0.0; 3], f64::NAN).is_err());
    }

    #[test]
    fn thread_count_does_not_change_the_decision() {
        let s: Vec<f32> = (0..30_000)
            .map(|i| ((i as f32) * 0.731).sin() * 2.0 - 3.0)
            .collect();
        let a = with_threads(Some(1), || large_gaussians(&s, 2.0)).unwrap();
        let b = with_threads(Some(2), || large_gaussians(&s, 2.0)).unwrap();
        assert_eq!(a.0, b.0);
        assert_eq!(a.1.mean.to_bits(), b.1.mean.to_bits());
        assert_eq!(a.1.std.to_bits(), b.1.std.to_bits());
    }
}
