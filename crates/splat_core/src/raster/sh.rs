//! Real spherical harmonics up to degree 3 (the 3DGS basis and constants), evaluated only
//! to the active degree, with the gradient w.r.t. coefficients and view direction.

pub use glam::Vec3;

pub const C0: f32 = 0.282_094_8;
pub const C1: f32 = 0.488_602_52;
pub const C2: [f32; 5] = [
    1.092_548_4,
    -1.092_548_4,
    0.315_391_57,
    -1.092_548_4,
    0.546_274_24,
];
pub const C3: [f32; 7] = [
    -0.590_043_6,
    2.890_611_4,
    -0.457_045_8,
    0.373_176_34,
    -0.457_045_8,
    1.445_305_7,
    -0.590_043_6,
];

/// Number of basis functions of degree <= `degree`.
pub fn num_bases(degree: usize) -> usize {
    (degree + 1) * (degree + 1)
}

/// Unit view direction, or zero for a zero vector (gsplat's F.normalize convention).
pub fn normalise(d: Vec3) -> (Vec3, f32) {
    let n = d.length();
    if n > 0.0 && n.is_finite() {
        (d / n, n)
    } else {
        (Vec3::ZERO, 0.0)
    }
}

/// Basis values at unit direction `d`; entries past `num_bases(degree)` are zero.
pub fn basis(degree: usize, d: Vec3) -> [f32; 16] {
    let mut b = [0.0f32; 16];
    b[0] = C0;
    if degree == 0 {
        return b;
    }
    let (x, y, z) = (d.x, d.y, d.z);
    b[1] = -C1 * y;
    b[2] = C1 * z;
    b[3] = -C1 * x;
    if degree == 1 {
        return b;
    }
    let (xx, yy, zz, xy, yz, xz) = (x * x, y * y, z * z, x * y, y * z, x * z);
    b[4] = C2[0] * xy;
    b[5] = C2[1] * yz;
    b[6] = C2[2] * (2.0 * zz - xx - yy);
    b[7] = C2[3] * xz;
    b[8] = C2[4] * (xx - yy);
    if degree == 2 {
        return b;
    }
    b[9] = C3[0] * y * (3.0 * xx - yy);
    b[10] = C3[1] * xy * z;
    b[11] = C3[2] * y * (4.0 * zz - xx - yy);
    b[12] = C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
    b[13] = C3[4] * x * (4.0 * zz - xx - yy);
    b[14] = C3[5] * z * (xx - yy);
    b[15] = C3[6] * x * (xx - 3.0 * yy);
    b
}

/// d basis_k / d(x, y, z) at unit direction `d`, as rows.
fn basis_jacobian(degree: usize, d: Vec3) -> [Vec3; 16] {
    let mut j = [Vec3::ZERO; 16];
    if degree == 0 {
        return j;
    }
    let (x, y, z) = (d.x, d.y, d.z);
    j[1] = Vec3::new(0.0, -C1, 0.0);
    j[2] = Vec3::new(0.0, 0.0, C1);
    j[3] = Vec3::new(-C1, 0.0, 0.0);
    if degree == 1 {
        return j;
    }
    let (xx, yy, zz, xy, yz, xz) = (x * x, y * y, z * z, x * y, y * z, x * z);
    j[4] = C2[0] * Vec3::new(y, x, 0.0);
    j[5] = C2[1] * Vec3::new(0.0, z, y);
    j[6] = C2[2] * Vec3::new(-2.0 * x, -2.0 * y, 4.0 * z);
    j[7] = C2[3] * Vec3::new(z, 0.0, x);
    j[8] = C2[4] * Vec3::new(2.0 * x, -2.0 * y, 0.0);
    if degree == 2 {
        return j;
    }
    j[9] = C3[0] * Vec3::new(6.0 * xy, 3.0 * xx - 3.0 * yy, 0.0);
    j[10] = C3[1] * Vec3::new(yz, xz, xy);
    j[11] = C3[2] * Vec3::new(-2.0 * xy, 4.0 * zz - xx - 3.0 * yy, 8.0 * yz);
    j[12] = C3[3] * Vec3::new(-6.0 * xz, -6.0 * yz, 6.0 * zz - 3.0 * xx - 3.0 * yy);
    j[13] = C3[4] * Vec3::new(4.0 * zz - 3.0 * xx - yy, -2.0 * xy, 8.0 * xz);
    j[14] = C3[5] * Vec3::new(2.0 * xz, -2.0 * yz, xx - yy);
    j[15] = C3[6] * Vec3::new(3.0 * xx - 3.0 * yy, -6.0 * xy, 0.0);
    j
}

/// SH value (before the +0.5 offset and clamp) for one Gaussian.
/// `coeffs` holds K rows of 3 channels, K >= num_bases(degree).
pub fn eval(degree: usize, coeffs: &[f32], dir: Vec3) -> [f32; 3] {
    let (d, _) = normalise(dir);
    let b = basis(degree, d);
    let mut out = [0.0f32; 3];
    for (k, bk) in b.iter().enumerate().take(num_bases(degree)) {
        for c in 0..3 {
            out[c] += bk * coeffs[3 * k + c];
        }
    }
    out
}

/// Backward of `eval`: adds dL/dcoeffs into `v_coeffs` (when given) and returns dL/d`dir`.
pub fn eval_backward(
    degree: usize,
    coeffs: &[f32],
    dir: Vec3,
    v_out: [f32; 3],
    v_coeffs: Option<&mut [f32]>,
) -> Vec3 {
    let (d, norm) = normalise(dir);
    let n = num_bases(degree);
    if let Some(vc) = v_coeffs {
        let b = basis(degree, d);
        for k in 0..n {
            for c in 0..3 {
                vc[3 * k + c] += b[k] * v_out[c];
            }
        }
    }
    if degree == 0 || norm == 0.0 {
        return Vec3::ZERO;
    }
    let jac = basis_jacobian(degree, d);
    let mut v_d = Vec3::ZERO;
    for k in 1..n {
        let w: f32 = (0..3).map(|c| coeffs[3 * k + c] * v_out[c]).sum();
        v_d += w * jac[k];
    }
    // Through the normalisation d = dir / |dir|.
    (v_d - d * d.dot(v_d)) / norm
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn degree_zero_is_constant() {
        let c = [1.0, 2.0, 3.0];
        assert_eq!(
            eval(0, &c, Vec3::new(0.3, 0.1, -2.0)),
            [C0, 2.0 * C0, 3.0 * C0]
        );
    }

    #[test]
    fn zero_direction_is_finite() {
        let c = [0.5f32; 48];
        let v = eval(3, &c, Vec3::ZERO);
        assert!(v.iter().all(|x| x.is_finite()));
        let g = eval_backward(3, &c, Vec3::ZERO, [1.0; 3], None);
        assert_eq!(g, Vec3::ZERO);
    }

    #[test]
    fn direction_gradient_matches_finite_differences() {
        let coeffs: Vec<f32> = (0..48)
            .map(|i| ((i * 37 % 11) as f32 - 5.0) * 0.1)
            .collect();
        let dir = Vec3::new(0.4, -0.7, 1.3);
        let v = [0.3, -1.0, 0.6];
        let loss = |d: Vec3| -> f64 {
            let o = eval(3, &coeffs, d);
            (0..3).map(|c| o[c] as f64 * v[c] as f64).sum()
        };
        let g = eval_backward(3, &coeffs, dir, v, None);
        for i in 0..3 {
            let h = 1e-3;
            let mut e = Vec3::ZERO;
            e[i] = h;
            let fd = (loss(dir + e) - loss(dir - e)) / (2.0 * h as f64);
            assert!((fd - g[i] as f64).abs() < 1e-3, "{i}: {fd} vs {}", g[i]);
        }
    }
}
