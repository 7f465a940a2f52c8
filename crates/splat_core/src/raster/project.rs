//! EWA projection of one 3D Gaussian to a 2D splat (gsplat 1.5 "classic" rules), and its
//! backward pass.
//!
//! Forward: normalise the quaternion, Sigma = R S S^T R^T, move it to camera space, apply the
//! EWA Jacobian with gsplat's clamp of x/z and y/z to 1.3x the field of view, add `eps2d` to
//! the diagonal, invert to the conic, and size the footprint box. The backward recomputes
//! these intermediates from the inputs instead of storing them (O(1) memory per Gaussian);
//! the backward pass runs it eight Gaussians at a time with the same bits
//! (`project_backward_batch`), and `project_backward` is its reference.
//! The forward rasterizer runs these rules eight Gaussians at a time (`project_batch`);
//! `project` is their per-Gaussian reference.

use std::ops::{Add, Div, Mul, Neg, Sub};

use glam::{Mat3, Vec3};

use super::camera::Camera;
use super::options::{Footprint, RasterOptions, ALPHA_MIN};

/// Squared quaternion norms below this cull the Gaussian: its rotation is undefined and the
/// normalisation gradient (1/|q|) would overflow.
pub const QUAT_NORM2_MIN: f32 = 1e-24;

/// One projected Gaussian. `radius == [0, 0]` marks a culled Gaussian.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Splat {
    /// Centre in pixels (pixel centres are at +0.5).
    pub xy: [f32; 2],
    /// Inverse of the blurred 2D covariance: (a, b, c) of [[a, b], [b, c]].
    pub conic: [f32; 3],
    /// Opacity used for blending (times the compensation in antialiased mode).
    pub opacity: f32,
    /// Camera-space z of the centre.
    pub depth: f32,
    /// Half-sizes of the footprint box in pixels (ceiled, as gsplat's radii).
    pub radius: [f32; 2],
    /// Footprint extent in standard deviations; the ellipse q(d) <= extent^2 is the footprint.
    pub extent: f32,
    /// Half-sizes in pixels of the box around the ellipse q(d) <= 2 ln(255 opacity), outside
    /// which alpha < 1/255: sqrt(2 ln(255 opacity) Sigma_xx) and likewise in y.
    pub half: [f32; 2],
}

impl Splat {
    pub fn visible(&self) -> bool {
        self.radius[0] > 0.0 || self.radius[1] > 0.0
    }
}

/// The parameters of one Gaussian, activated (linear scales, opacity in [0, 1]).
#[derive(Debug, Clone, Copy)]
pub struct Gaussian3 {
    pub mean: Vec3,
    pub quat: [f32; 4],
    pub scale: Vec3,
    pub opacity: f32,
}

impl Gaussian3 {
    fn finite(&self) -> bool {
        self.mean.is_finite()
            && self.quat.iter().all(|v| v.is_finite())
            && self.scale.is_finite()
            && self.opacity.is_finite()
    }
}

/// Rotation matrix of the normalised (w, x, y, z) quaternion, or None when |q| is ~0.
pub fn quat_to_rotmat(q: [f32; 4]) -> Option<(Mat3, [f32; 4], f32)> {
    let n2 = q.iter().map(|v| v * v).sum::<f32>();
    if !(n2.is_finite() && n2 >= QUAT_NORM2_MIN) {
        return None;
    }
    let norm = n2.sqrt();
    let [w, x, y, z] = q.map(|v| v / norm);
    let r = Mat3::from_cols(
        Vec3::new(
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y + w * z),
            2.0 * (x * z - w * y),
        ),
        Vec3::new(
            2.0 * (x * y - w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z + w * x),
        ),
        Vec3::new(
            2.0 * (x * z + w * y),
            2.0 * (y * z - w * x),
            1.0 - 2.0 * (x * x + y * y),
        ),
    );
    Some((r, [w, x, y, z], norm))
}

/// Gradient of the loss w.r.t. the unnormalised quaternion, given dL/dR.
fn rotmat_backward(g: Mat3, qn: [f32; 4], norm: f32) -> [f32; 4] {
    // g.col(j)[i] = dL/dR_ij
    quat_grad(|i, j| g.col(j)[i], qn, norm)
}

/// `rotmat_backward` written once for one value (`f32`) or eight (`batch_lanes::Lanes`,
/// `project_backward_batch`): the same operations in the same order, so both give the same
/// bits. `e(i, j)` is dL/dR_ij.
#[inline(always)]
pub(super) fn quat_grad<T>(e: impl Fn(usize, usize) -> T, qn: [T; 4], norm: T) -> [T; 4]
where
    T: Copy + Add<Output = T> + Sub<Output = T> + Mul<Output = T> + Div<Output = T>,
    T: Neg<Output = T>,
    f32: Mul<T, Output = T>,
{
    let [w, x, y, z] = qn;
    let dw =
        2.0 * (-z * e(0, 1) + y * e(0, 2) + z * e(1, 0) - x * e(1, 2) - y * e(2, 0) + x * e(2, 1));
    let dx = 2.0
        * (y * e(0, 1) + z * e(0, 2) + y * e(1, 0) - 2.0 * x * e(1, 1) - w * e(1, 2)
            + z * e(2, 0)
            + w * e(2, 1)
            - 2.0 * x * e(2, 2));
    let dy = 2.0
        * (-2.0 * y * e(0, 0) + x * e(0, 1) + w * e(0, 2) + x * e(1, 0) + z * e(1, 2)
            - w * e(2, 0)
            + z * e(2, 1)
            - 2.0 * y * e(2, 2));
    let dz = 2.0
        * (-2.0 * z * e(0, 0) - w * e(0, 1) + x * e(0, 2) + w * e(1, 0) - 2.0 * z * e(1, 1)
            + y * e(1, 2)
            + x * e(2, 0)
            + y * e(2, 1));
    let dn = [dw, dx, dy, dz];
    // A sum of f32 starting at -0.0 (as `Sum` does) leaves its first term as it is.
    let dot = ((dn[0] * qn[0] + dn[1] * qn[1]) + dn[2] * qn[2]) + dn[3] * qn[3];
    let out = |i: usize| (dn[i] - qn[i] * dot) / norm;
    [out(0), out(1), out(2), out(3)]
}

/// Everything the forward computes, kept together so the backward can reuse it.
struct Intermediates {
    rot: Mat3,
    qn: [f32; 4],
    qnorm: f32,
    p: Vec3,
    cov_c: Mat3,
    j0: Vec3,
    j1: Vec3,
    /// Clamped camera-space x and y used in the Jacobian.
    tx: f32,
    ty: f32,
    /// Whether x/z and y/z were inside the clamp limits.
    x_free: bool,
    y_free: bool,
    /// Blurred 2D covariance (a, b, c).
    cov: [f32; 3],
    det0: f32,
    det: f32,
    conic: [f32; 3],
    compensation: f32,
}

fn intermediates(g: &Gaussian3, cam: &Camera, opts: &RasterOptions) -> Option<Intermediates> {
    if !g.finite() {
        return None;
    }
    let p = cam.to_camera(g.mean);
    if !(p.z >= opts.near_plane && p.z <= opts.far_plane) {
        return None;
    }
    let (rot, qn, qnorm) = quat_to_rotmat(g.quat)?;
    let m = rot * Mat3::from_diagonal(g.scale);
    let cov_c = cam.rot * (m * m.transpose()) * cam.rot.transpose();

    let [lim_xp, lim_xn, lim_yp, lim_yn] = cam.jacobian_limits();
    let rz = 1.0 / p.z;
    let (u, v) = (p.x * rz, p.y * rz);
    let x_free = u <= lim_xp && u >= -lim_xn;
    let y_free = v <= lim_yp && v >= -lim_yn;
    let tx = p.z * u.clamp(-lim_xn, lim_xp);
    let ty = p.z * v.clamp(-lim_yn, lim_yp);
    let j0 = Vec3::new(cam.fx * rz, 0.0, -cam.fx * tx * rz * rz);
    let j1 = Vec3::new(0.0, cam.fy * rz, -cam.fy * ty * rz * rz);
    let (cj0, cj1) = (cov_c * j0, cov_c * j1);
    let (a0, b, c0) = (j0.dot(cj0), j0.dot(cj1), j1.dot(cj1));
    let det0 = a0 * c0 - b * b;
    let (a, c) = (a0 + opts.eps2d, c0 + opts.eps2d);
    let det = a * c - b * b;
    if !(det.is_finite() && det > 0.0) {
        return None;
    }
    let conic = [c / det, -b / det, a / det];
    if !conic.iter().all(|v| v.is_finite()) {
        return None;
    }
    let compensation = if opts.antialiased {
        (det0 / det).max(0.0).sqrt()
    } else {
        1.0
    };
    Some(Intermediates {
        rot,
        qn,
        qnorm,
        p,
        cov_c,
        j0,
        j1,
        tx,
        ty,
        x_free,
        y_free,
        cov: [a, b, c],
        det0,
        det,
        conic,
        compensation,
    })
}

/// 2 ln(255 opacity): where q(d) = d^T conic d exceeds it, alpha < 1/255.
fn alpha_contour(opacity: f32) -> f32 {
    2.0 * (opacity / ALPHA_MIN).ln().max(0.0)
}

pub(super) fn extent_for_contour(rule: Footprint, qmax: f32) -> f32 {
    match rule {
        Footprint::OpacityAware => 3.33f32.min(qmax.sqrt()),
        Footprint::Sigma(k) => k,
    }
}

/// Footprint extent in standard deviations for a blending opacity.
pub fn footprint_extent(rule: Footprint, opacity: f32) -> f32 {
    extent_for_contour(rule, alpha_contour(opacity))
}

/// `v.ceil()` for v >= 0 (or NaN) without libm: `ceilf` is an out-of-line call on
/// baseline x86-64, and this runs twice per Gaussian. Written with an i32 conversion, which
/// SSE2 has in SIMD form, so that `project_batch` vectorises it.
#[inline(always)]
pub(super) fn ceil_nonneg(v: f32) -> f32 {
    // From 2^23 on every float is an integer; NaN takes the else branch and stays NaN.
    if v < 8_388_608.0 {
        let t = v as i32 as f32;
        if t < v {
            t + 1.0
        } else {
            t
        }
    } else {
        v
    }
}

/// Projects one Gaussian; a culled Gaussian gives `Splat::default()` (radius 0).
pub fn project(g: &Gaussian3, cam: &Camera, opts: &RasterOptions) -> Splat {
    let Some(it) = intermediates(g, cam, opts) else {
        return Splat::default();
    };
    let opacity = g.opacity * it.compensation;
    if opacity.is_nan() || opacity < ALPHA_MIN {
        return Splat::default();
    }
    let qmax = alpha_contour(opacity);
    let extent = extent_for_contour(opts.footprint, qmax);
    let radius = [
        ceil_nonneg(extent * it.cov[0].sqrt()),
        ceil_nonneg(extent * it.cov[2].sqrt()),
    ];
    if radius[0] <= 0.0 && radius[1] <= 0.0 {
        return Splat::default();
    }
    let rz = 1.0 / it.p.z;
    let xy = [cam.fx * it.p.x * rz + cam.cx, cam.fy * it.p.y * rz + cam.cy];
    let (w, h) = (cam.width as f32, cam.height as f32);
    if !(xy[0] + radius[0] > 0.0
        && xy[0] - radius[0] < w
        && xy[1] + radius[1] > 0.0
        && xy[1] - radius[1] < h)
    {
        return Splat::default();
    }
    Splat {
        xy,
        conic: it.conic,
        opacity,
        depth: it.p.z,
        radius,
        extent,
        half: [(qmax * it.cov[0]).sqrt(), (qmax * it.cov[2]).sqrt()],
    }
}

/// Gradients arriving at one projected Gaussian from the blending stage.
#[derive(Debug, Clone, Copy, Default)]
pub struct SplatGrad {
    pub xy: [f32; 2],
    pub conic: [f32; 3],
    pub opacity: f32,
    pub depth: f32,
}

/// Gradients of one Gaussian's parameters (plus the camera-space mean, for SH directions
/// the caller adds separately).
#[derive(Debug, Clone, Copy, Default)]
pub struct Gaussian3Grad {
    pub mean: Vec3,
    pub quat: [f32; 4],
    pub scale: Vec3,
    pub opacity: f32,
}

/// Backward of `project` for a Gaussian that was visible.
pub fn project_backward(
    g: &Gaussian3,
    cam: &Camera,
    opts: &RasterOptions,
    v: &SplatGrad,
) -> Gaussian3Grad {
    let Some(it) = intermediates(g, cam, opts) else {
        return Gaussian3Grad::default();
    };
    let [ca, cb, cc] = it.conic;
    // Conic parameters -> full-matrix gradient (b appears twice in the quadratic form).
    let (ga, gb, gc) = (v.conic[0], 0.5 * v.conic[1], v.conic[2]);
    // dL/dSigma = -Q G Q for Q = Sigma^-1 (all 2x2 symmetric).
    let qg00 = ca * ga + cb * gb;
    let qg01 = ca * gb + cb * gc;
    let qg10 = cb * ga + cc * gb;
    let qg11 = cb * gb + cc * gc;
    let mut s00 = -(qg00 * ca + qg01 * cb);
    let mut s01 = -(qg00 * cb + qg01 * cc);
    let mut s11 = -(qg10 * cb + qg11 * cc);

    let v_opacity = v.opacity * it.compensation;
    if opts.antialiased {
        // comp = sqrt(r), r = det0 / det: dr/dSigma = (1 - r) Q - eps2d / det I.
        let r = it.det0 / it.det;
        if r > 0.0 && it.compensation > 0.0 {
            let v_r = v.opacity * g.opacity * 0.5 / it.compensation;
            let e = opts.eps2d / it.det;
            s00 += v_r * ((1.0 - r) * ca - e);
            s01 += v_r * (1.0 - r) * cb;
            s11 += v_r * ((1.0 - r) * cc - e);
        }
    }

    // Sigma = J C J^T: dL/dC = J^T S J, dL/dJ = 2 S J C (rows).
    let (j0, j1) = (it.j0, it.j1);
    let sj0 = s00 * j0 + s01 * j1;
    let sj1 = s01 * j0 + s11 * j1;
    let g_cov_c = Mat3::from_cols(
        sj0 * j0.x + sj1 * j1.x,
        sj0 * j0.y + sj1 * j1.y,
        sj0 * j0.z + sj1 * j1.z,
    );
    // J^T S J = j0 sj0^T + j1 sj1^T; the expression above is its transpose, equal by symmetry.
    let gj0 = 2.0 * (it.cov_c * sj0);
    let gj1 = 2.0 * (it.cov_c * sj1);

    let (fx, fy) = (cam.fx, cam.fy);
    let p = it.p;
    let rz = 1.0 / p.z;
    let rz2 = rz * rz;
    let rz3 = rz2 * rz;
    let mut v_p = Vec3::new(
        fx * rz * v.xy[0],
        fy * rz * v.xy[1],
        -(fx * p.x * v.xy[0] + fy * p.y * v.xy[1]) * rz2 + v.depth,
    );
    // J entries: J00 = fx/z, J11 = fy/z, J02 = -fx tx/z^2, J12 = -fy ty/z^2.
    v_p.z += -fx * rz2 * gj0.x - fy * rz2 * gj1.y;
    let (tx, ty) = (it.tx, it.ty);
    if it.x_free {
        v_p.x += -fx * rz2 * gj0.z;
        v_p.z += 2.0 * fx * tx * rz3 * gj0.z;
    } else {
        v_p.z += fx * tx * rz3 * gj0.z;
    }
    if it.y_free {
        v_p.y += -fy * rz2 * gj1.z;
        v_p.z += 2.0 * fy * ty * rz3 * gj1.z;
    } else {
        v_p.z += fy * ty * rz3 * gj1.z;
    }
    let w = cam.rot;
    let v_mean = w.transpose() * v_p;

    // C = W V W^T, V = M M^T, M = R S.
    let g_v = w.transpose() * g_cov_c * w;
    let g_v = g_v + g_v.transpose();
    let m = it.rot * Mat3::from_diagonal(g.scale);
    let g_m = g_v * m; // = 2 sym(G_V) M, using the symmetrised G_V above
    let s = g.scale;
    let v_scale = Vec3::new(
        g_m.x_axis.dot(it.rot.x_axis),
        g_m.y_axis.dot(it.rot.y_axis),
        g_m.z_axis.dot(it.rot.z_axis),
    );
    let g_r = Mat3::from_cols(g_m.x_axis * s.x, g_m.y_axis * s.y, g_m.z_axis * s.z);
    let v_quat = rotmat_backward(g_r, it.qn, it.qnorm);
    Gaussian3Grad {
        mean: v_mean,
        quat: v_quat,
        scale: v_scale,
        opacity: v_opacity,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ceil_nonneg_matches_ceil() {
        let mut v = 0.0f32;
        while v < 100.0 {
            for w in [v, f32::from_bits(v.to_bits() + 1), v + 0.5] {
                assert_eq!(ceil_nonneg(w).to_bits(), w.ceil().to_bits(), "{w}");
            }
            v += 0.25;
        }
        for w in [8_388_607.5f32, 8_388_608.0, 1e30, f32::INFINITY] {
            assert_eq!(ceil_nonneg(w), w.ceil());
        }
        assert!(ceil_nonneg(f32::NAN).is_nan());
    }

    #[test]
    fn identity_quaternion_gives_identity_rotation() {
        let (r, _, n) = quat_to_rotmat([2.0, 0.0, 0.0, 0.0]).unwrap();
        assert_eq!(r, Mat3::IDENTITY);
        assert_eq!(n, 2.0);
        assert!(quat_to_rotmat([0.0; 4]).is_none());
        assert!(quat_to_rotmat([f32::NAN, 0.0, 0.0, 1.0]).is_none());
    }

    #[test]
    fn rotation_is_orthonormal() {
        let (r, _, _) = quat_to_rotmat([0.3, -0.5, 0.7, 0.2]).unwrap();
        let e = (r * r.transpose() - Mat3::IDENTITY).abs().to_cols_array();
        assert!(e.iter().all(|v| *v < 1e-6));
        assert!((r.determinant() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn rotmat_gradient_matches_finite_differences() {
        let q = [0.3f32, -0.5, 0.7, 0.2];
        // loss = sum(G .* R) for a fixed G
        let g = Mat3::from_cols_array(&[0.1, -0.2, 0.3, 0.4, 0.5, -0.6, 0.7, -0.8, 0.9]);
        let loss = |q: [f32; 4]| -> f64 {
            let (r, _, _) = quat_to_rotmat(q).unwrap();
            let (a, b) = (r.to_cols_array(), g.to_cols_array());
            (0..9).map(|i| a[i] as f64 * b[i] as f64).sum()
        };
        let (_, qn, n) = quat_to_rotmat(q).unwrap();
        let grad = rotmat_backward(g, qn, n);
        for i in 0..4 {
            let h = 1e-3;
            let (mut qp, mut qm) = (q, q);
            qp[i] += h;
            qm[i] -= h;
            let fd = (loss(qp) - loss(qm)) / (2.0 * h as f64);
            assert!(
                (fd - grad[i] as f64).abs() < 2e-3,
                "{i}: fd {fd} vs {}",
                grad[i]
            );
        }
    }

    #[test]
    fn opacity_aware_extent_is_the_alpha_contour() {
        // alpha = o exp(-e^2 / 2) == 1/255 at the extent.
        for o in [0.01f32, 0.1, 0.5, 0.9] {
            let e = footprint_extent(Footprint::OpacityAware, o);
            assert!((o * (-0.5 * e * e).exp() - ALPHA_MIN).abs() < 1e-6);
        }
        // The 3.33 cap only binds above opacity 1.003 (sqrt(2 ln 255) = 3.329).
        assert!(footprint_extent(Footprint::OpacityAware, 1.0) < 3.33);
        assert_eq!(footprint_extent(Footprint::OpacityAware, 2.0), 3.33);
    }
}
