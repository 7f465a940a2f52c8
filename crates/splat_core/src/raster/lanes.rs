//! The vocabulary of the lane kernels: lane groups of eight pixels, the exp polynomial, the
//! sigma expression and the lane-sum tree. Every blending kernel (forward, backward, scalar,
//! AVX2) builds on these, so all of them perform the same operations in the same order and
//! give the same bits.

/// Pixels per lane group: eight f32 lanes fill an AVX2 register.
pub(super) const LANES: usize = 8;

/// exp(x) for x <= 0 (the kernels pass -sigma) from + and * only: Cody-Waite reduction and
/// Cephes' polynomial, accurate to 2 ulp. libm's `expf` is an opaque call: the blending loop
/// could not be vectorised around it, and the forward and backward passes must agree to
/// the bit. The polynomial is evaluated in Estrin's form, whose dependency chain is 4
/// operations shorter than Horner's: the blending loop is bound by this latency.
#[inline(always)]
pub(super) fn exp_neg(x: f32) -> f32 {
    // Below -87 the result would be subnormal; the callers discard it anyway (< 1/255).
    // Written as a comparison so that NaN maps to -87 in every lane. No upper clamp: x is
    // -sigma <= 0 up to rounding, and exact up to x = 88 anyway.
    let x = if x > -87.0 { x } else { -87.0 };
    // Adding 1.5 * 2^23 rounds x / ln 2 to the nearest integer n, left in the low bits.
    const ROUND: f32 = 12_582_912.0;
    let t = x * std::f32::consts::LOG2_E + ROUND;
    let n = t - ROUND;
    // ln 2 = C1 + C2 with C1 exact in 9 bits, so n * C1 is exact.
    let r = (x - n * 0.693_359_4) - n * -2.121_944_4e-4;
    let (r2, c) = (r * r, EXP_COEFFS);
    let r4 = r2 * r2;
    let p = (c[0] * r + c[1]) * r4 + ((c[2] * r + c[3]) * r2 + (c[4] * r + c[5]));
    let y = (p * r2 + r) + 1.0;
    // 2^n as bits: n is in [-126, 127], so the biased exponent stays in [1, 254].
    let n_int = t.to_bits().wrapping_sub(ROUND.to_bits());
    let scale = f32::from_bits(n_int.wrapping_add(127).wrapping_shl(23));
    y * scale
}

/// exp(r) = 1 + r + r^2 (c0 r^5 + c1 r^4 + ... + c5) on |r| <= ln(2) / 2 (Cephes expf).
pub(super) const EXP_COEFFS: [f32; 6] = [
    1.987_569_2e-4,
    1.398_199_9e-3,
    8.333_452e-3,
    4.166_579_6e-2,
    1.666_666_5e-1,
    0.5,
];

/// sigma at a pixel, from the row terms c dy^2 and b dy. Every kernel (forward, backward,
/// scalar, AVX2) evaluates exactly this expression, so all see the same alphas.
#[inline(always)]
pub(super) fn sigma_at(a: f32, dx: f32, c_dy2: f32, b_dy: f32) -> f32 {
    0.5 * (a * dx * dx + c_dy2) + dx * b_dy
}

/// Sum of eight lanes in the tree the AVX2 kernel uses: (l0+l4 + l2+l6) + (l1+l5 + l3+l7).
#[inline(always)]
pub(super) fn lane_sum(v: &[f32; LANES]) -> f32 {
    let s = [v[0] + v[4], v[1] + v[5], v[2] + v[6], v[3] + v[7]];
    (s[0] + s[2]) + (s[1] + s[3])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_neg_is_accurate_and_total() {
        let mut worst = 0.0f64;
        let mut x = 0.0f32;
        while x > -87.0 {
            let rel = ((exp_neg(x) as f64) / (x as f64).exp() - 1.0).abs();
            worst = worst.max(rel);
            x -= 0.000_731;
        }
        // 2 ulp at 1 is 2.4e-7.
        assert!(worst < 2.4e-7, "worst relative error {worst:e}");
        assert_eq!(exp_neg(0.0), 1.0);
        assert_eq!(exp_neg(-0.0), 1.0);
        // NaN and far-negative inputs give finite values in [0, 1] (callers mask them).
        for v in [f32::NAN, f32::NEG_INFINITY, -1e30] {
            let e = exp_neg(v);
            assert!(e.is_finite() && (0.0..=1.0).contains(&e), "{v} -> {e}");
        }
        // Slightly positive x (-sigma after rounding) is still exp(x).
        assert!((exp_neg(1e-6) - 1.000_001).abs() < 2e-7);
    }
}
