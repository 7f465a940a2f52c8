//! `project::project_backward` eight Gaussians at a time, with the same bits.
//!
//! The per-Gaussian backward recomputes the projection's intermediates and chains through
//! them: a few hundred scalar products, divisions and square roots per Gaussian, which made
//! it about a quarter of the whole backward. Here every formula runs on `Lanes` of eight
//! Gaussians with the operands and the order of the glam expressions in `project` (products
//! with the zeros of `Mat3::from_diagonal` and of the Jacobian included), and each branch
//! becomes a per-lane select of the branch's own result, so every lane computes exactly
//! what the scalar code computes: the gradients are bit-identical (`tests`), and
//! `project_backward` stays the reference.

use super::batch_lanes::{Lanes, M3, N, V3};
use super::camera::Camera;
use super::options::RasterOptions;
use super::project::{quat_grad, Gaussian3Grad, QUAT_NORM2_MIN};
use super::scene::Scene;

/// Eight Gaussians' parameters, one per lane.
pub(super) struct GaussianLanes {
    pub mean: V3,
    pub quat: [Lanes; 4],
    pub scale: V3,
    pub opacity: Lanes,
}

impl GaussianLanes {
    /// Gaussians `idx[0]`, ..., `idx[7]` of the scene.
    #[inline(always)]
    pub fn load(scene: &Scene, idx: &[usize; N]) -> Self {
        let load =
            |v: &[f32], w: usize, c: usize| Lanes(std::array::from_fn(|l| v[idx[l] * w + c]));
        Self {
            mean: V3(std::array::from_fn(|c| load(&scene.means, 3, c))),
            quat: std::array::from_fn(|c| load(&scene.quats, 4, c)),
            scale: V3(std::array::from_fn(|c| load(&scene.scales, 3, c))),
            opacity: load(&scene.opacities, 1, 0),
        }
    }
}

/// Eight splats' incoming gradients, one per lane.
pub(super) struct SplatGradLanes {
    pub xy: [Lanes; 2],
    pub conic: [Lanes; 3],
    pub opacity: Lanes,
    pub depth: Lanes,
}

impl SplatGradLanes {
    /// From rows of per-splat sums (`stride` values: xy, conic, opacity, features), row
    /// `rows[l]` for lane l, and the depth gradient at `depth` in the row if there is one.
    #[inline(always)]
    pub fn load(sums: &[f32], stride: usize, rows: &[usize; N], depth: Option<usize>) -> Self {
        let load = |c: usize| Lanes(std::array::from_fn(|l| sums[rows[l] * stride + c]));
        Self {
            xy: std::array::from_fn(load),
            conic: std::array::from_fn(|c| load(2 + c)),
            opacity: load(5),
            depth: depth.map_or(Lanes::splat(0.0), load),
        }
    }
}

/// The camera as the lanes read it.
pub(super) struct CameraLanes {
    rot: M3,
    rot_t: M3,
    trans: V3,
    /// Jacobian clamp limits (right, left, down, up) of x/z and y/z.
    lim: [f32; 4],
    fx: f32,
    fy: f32,
}

impl CameraLanes {
    pub fn new(cam: &Camera) -> Self {
        let rot = M3::splat(cam.rot.to_cols_array_2d());
        Self {
            rot,
            rot_t: rot.transpose(),
            trans: V3(cam.trans.to_array().map(Lanes::splat)),
            lim: cam.jacobian_limits(),
            fx: cam.fx,
            fy: cam.fy,
        }
    }
}

/// `project_backward` of eight Gaussians; a lane whose Gaussian the projection culls gets
/// zeros, as there.
pub(super) fn project_backward_lanes(
    g: &GaussianLanes,
    cam: &CameraLanes,
    opts: &RasterOptions,
    v: &SplatGradLanes,
) -> [Gaussian3Grad; N] {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        #[allow(unsafe_code)]
        // SAFETY: the CPU has AVX (checked just above).
        return unsafe { lanes_avx(g, cam, opts, v) };
    }
    lanes(g, cam, opts, v)
}

/// `lanes` compiled for AVX: one 8-wide instruction per lane operation instead of two
/// 4-wide SSE ones. The operations are the same (no fused multiply-add), so are the bits.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
fn lanes_avx(
    g: &GaussianLanes,
    cam: &CameraLanes,
    opts: &RasterOptions,
    v: &SplatGradLanes,
) -> [Gaussian3Grad; N] {
    lanes(g, cam, opts, v)
}

#[inline(always)]
fn lanes(
    g: &GaussianLanes,
    cam: &CameraLanes,
    opts: &RasterOptions,
    v: &SplatGradLanes,
) -> [Gaussian3Grad; N] {
    let one = Lanes::splat(1.0);
    // --- `project::intermediates` ---
    let p = cam.rot.mul_vec(g.mean).add(cam.trans);
    // `quat_to_rotmat`
    let q = g.quat;
    let n2 = ((q[0] * q[0] + q[1] * q[1]) + q[2] * q[2]) + q[3] * q[3];
    let qnorm = n2.sqrt();
    let [w, x, y, z] = [q[0] / qnorm, q[1] / qnorm, q[2] / qnorm, q[3] / qnorm];
    let rot = M3([
        V3([
            one - 2.0 * (y * y + z * z),
            2.0 * (x * y + w * z),
            2.0 * (x * z - w * y),
        ]),
        V3([
            2.0 * (x * y - w * z),
            one - 2.0 * (x * x + z * z),
            2.0 * (y * z + w * x),
        ]),
        V3([
            2.0 * (x * z + w * y),
            2.0 * (y * z - w * x),
            one - 2.0 * (x * x + y * y),
        ]),
    ]);
    let m = rot.mul(&M3::diagonal(g.scale));
    let cov_c = cam.rot.mul(&m.mul(&m.transpose())).mul(&cam.rot_t);

    let [lim_xp, lim_xn, lim_yp, lim_yn] = cam.lim;
    let pz = p.0[2];
    let rz = one / pz;
    let (u, vv) = (p.0[0] * rz, p.0[1] * rz);
    let x_free = u.mask(|u| u <= lim_xp && u >= -lim_xn);
    let y_free = vv.mask(|v| v <= lim_yp && v >= -lim_yn);
    let tx = pz * u.map(|u| u.clamp(-lim_xn, lim_xp));
    let ty = pz * vv.map(|v| v.clamp(-lim_yn, lim_yp));
    let (fx, fy) = (cam.fx, cam.fy);
    let zero = Lanes::splat(0.0);
    let j0 = V3([fx * rz, zero, -fx * tx * rz * rz]);
    let j1 = V3([zero, fy * rz, -fy * ty * rz * rz]);
    let (cj0, cj1) = (cov_c.mul_vec(j0), cov_c.mul_vec(j1));
    let (a0, b, c0) = (j0.dot(cj0), j0.dot(cj1), j1.dot(cj1));
    let det0 = a0 * c0 - b * b;
    let (a, c) = (a0 + opts.eps2d, c0 + opts.eps2d);
    let det = a * c - b * b;
    let conic = [c / det, -b / det, a / det];
    let compensation = if opts.antialiased {
        (det0 / det).map(|r| r.max(0.0).sqrt())
    } else {
        one
    };

    // --- `project_backward` ---
    let [ca, cb, cc] = conic;
    let (ga, gb, gc) = (v.conic[0], 0.5 * v.conic[1], v.conic[2]);
    let qg00 = ca * ga + cb * gb;
    let qg01 = ca * gb + cb * gc;
    let qg10 = cb * ga + cc * gb;
    let qg11 = cb * gb + cc * gc;
    let mut s00 = -(qg00 * ca + qg01 * cb);
    let mut s01 = -(qg00 * cb + qg01 * cc);
    let mut s11 = -(qg10 * cb + qg11 * cc);

    let v_opacity = v.opacity * compensation;
    if opts.antialiased {
        let r = det0 / det;
        let on: [bool; N] = std::array::from_fn(|l| r.0[l] > 0.0 && compensation.0[l] > 0.0);
        let v_r = v.opacity * g.opacity * 0.5 / compensation;
        let e = opts.eps2d / det;
        s00 = (s00 + v_r * ((one - r) * ca - e)).select(on, s00);
        s01 = (s01 + v_r * (one - r) * cb).select(on, s01);
        s11 = (s11 + v_r * ((one - r) * cc - e)).select(on, s11);
    }

    let sj0 = j0.scale(s00).add(j1.scale(s01));
    let sj1 = j0.scale(s01).add(j1.scale(s11));
    let g_cov_c = M3([
        sj0.scale(j0.0[0]).add(sj1.scale(j1.0[0])),
        sj0.scale(j0.0[1]).add(sj1.scale(j1.0[1])),
        sj0.scale(j0.0[2]).add(sj1.scale(j1.0[2])),
    ]);
    let gj0 = cov_c.mul_vec(sj0).scale(Lanes::splat(2.0));
    let gj1 = cov_c.mul_vec(sj1).scale(Lanes::splat(2.0));

    let rz2 = rz * rz;
    let rz3 = rz2 * rz;
    let [px, py, _] = p.0;
    let mut vpx = fx * rz * v.xy[0];
    let mut vpy = fy * rz * v.xy[1];
    let mut vpz = -(fx * px * v.xy[0] + fy * py * v.xy[1]) * rz2 + v.depth;
    vpz = vpz + (-fx * rz2 * gj0.0[0] - fy * rz2 * gj1.0[1]);
    vpx = (vpx + -fx * rz2 * gj0.0[2]).select(x_free, vpx);
    vpz = vpz + (2.0 * fx * tx * rz3 * gj0.0[2]).select(x_free, fx * tx * rz3 * gj0.0[2]);
    vpy = (vpy + -fy * rz2 * gj1.0[2]).select(y_free, vpy);
    vpz = vpz + (2.0 * fy * ty * rz3 * gj1.0[2]).select(y_free, fy * ty * rz3 * gj1.0[2]);
    let v_mean = cam.rot_t.mul_vec(V3([vpx, vpy, vpz]));

    let g_v = cam.rot_t.mul(&g_cov_c).mul(&cam.rot);
    let g_v = g_v.add(&g_v.transpose());
    let g_m = g_v.mul(&m);
    let v_scale = [
        g_m.0[0].dot(rot.0[0]),
        g_m.0[1].dot(rot.0[1]),
        g_m.0[2].dot(rot.0[2]),
    ];
    let [s0, s1, s2] = g.scale.0;
    let g_r = M3([g_m.0[0].scale(s0), g_m.0[1].scale(s1), g_m.0[2].scale(s2)]);
    let v_quat = rotmat_backward(&g_r, [w, x, y, z], qnorm);

    // The culling of `intermediates`. 0 x is NaN exactly when x is NaN or infinite (else
    // +-0): one sum flags every non-finite input, another every non-finite result.
    let zero = Lanes::splat(0.0);
    let inputs = g.mean.0.iter().chain(&g.quat).chain(&g.scale.0);
    let probe_in = inputs.fold(g.opacity * zero, |acc, v| acc + *v * zero);
    let probe_out = n2 * zero + det * zero + conic[0] * zero + conic[1] * zero + conic[2] * zero;
    let (near, far) = (opts.near_plane, opts.far_plane);
    let mut out = [Gaussian3Grad::default(); N];
    for (l, o) in out.iter_mut().enumerate() {
        let at = |v: Lanes| v.0[l];
        let kept = at(probe_in) == 0.0
            && at(probe_out) == 0.0
            && (at(pz) >= near && at(pz) <= far)
            && at(n2) >= QUAT_NORM2_MIN
            && at(det) > 0.0;
        if kept {
            *o = Gaussian3Grad {
                mean: glam::Vec3::new(at(v_mean.0[0]), at(v_mean.0[1]), at(v_mean.0[2])),
                quat: [at(v_quat[0]), at(v_quat[1]), at(v_quat[2]), at(v_quat[3])],
                scale: glam::Vec3::new(at(v_scale[0]), at(v_scale[1]), at(v_scale[2])),
                opacity: at(v_opacity),
            };
        }
    }
    out
}

/// `project::rotmat_backward` on lanes.
#[inline(always)]
fn rotmat_backward(g: &M3, qn: [Lanes; 4], norm: Lanes) -> [Lanes; 4] {
    quat_grad(|i, j| g.0[j].0[i], qn, norm)
}

#[cfg(test)]
mod tests {
    use super::super::project::{project_backward, Gaussian3, SplatGrad};
    use super::super::test_gaussians::{GaussianLists, DEGENERATE, SUB_PIXEL};
    use super::*;
    use crate::test_rng::Lcg;

    fn camera() -> Camera {
        let (s, c) = (0.4f32.sin(), 0.4f32.cos());
        let view = [
            c, 0.0, s, 0.2, //
            0.0, 1.0, 0.0, -0.1, //
            -s, 0.0, c, 4.0, //
            0.0, 0.0, 0.0, 1.0,
        ];
        let k = [200.0, 0.0, 160.0, 0.0, 210.0, 120.0, 0.0, 0.0, 1.0];
        Camera::from_matrices(&view, &k, 320, 240).unwrap()
    }

    /// Random Gaussians (in and out of view, round to needle-thin, some outside the
    /// Jacobian's clamp) and the degenerate ones the culling is about.
    fn scene(n: usize, seed: u64) -> Scene {
        let mut r = Lcg::new(seed);
        let mut gaussians = GaussianLists::default();
        for _ in 0..n {
            let spread = if r.uniform() < 0.2 { 12.0 } else { 4.0 };
            let mean = [
                spread * (r.uniform() - 0.5),
                spread * (r.uniform() - 0.5),
                8.0 * r.uniform() - 4.0,
            ];
            let quat = [0; 4].map(|_| r.uniform() - 0.5);
            let base = 10f32.powf(-3.0 + 2.5 * r.uniform());
            let scales = [
                base,
                base * (0.01 + r.uniform()),
                base * (0.01 + r.uniform()),
            ];
            gaussians.push((mean, quat, scales, r.uniform()));
        }
        DEGENERATE.into_iter().for_each(|g| gaussians.push(g));
        gaussians.push(SUB_PIXEL);
        gaussians.scene(&vec![0.5f32; gaussians.len() * 3])
    }

    #[test]
    fn lanes_give_the_per_gaussian_bits() {
        let cam = camera();
        let cl = CameraLanes::new(&cam);
        let mut r = Lcg::new(11);
        let mut nonzero = 0;
        for antialiased in [false, true] {
            let opts = RasterOptions {
                antialiased,
                ..Default::default()
            };
            let sc = scene(4000, 5 + antialiased as u64);
            for first in (0..sc.n).step_by(N) {
                let idx: [usize; N] = std::array::from_fn(|l| (first + l).min(sc.n - 1));
                let v: [SplatGrad; N] = std::array::from_fn(|_| SplatGrad {
                    xy: [r.uniform() - 0.5, r.uniform() - 0.5],
                    conic: [0; 3].map(|_| 10.0 * (r.uniform() - 0.5)),
                    opacity: r.uniform() - 0.5,
                    depth: r.uniform() - 0.5,
                });
                let stride = 7;
                let sums: Vec<f32> = v
                    .iter()
                    .flat_map(|g| {
                        [
                            g.xy[0], g.xy[1], g.conic[0], g.conic[1], g.conic[2], g.opacity,
                            g.depth,
                        ]
                    })
                    .collect();
                let rows = std::array::from_fn(|l| l);
                let vl = SplatGradLanes::load(&sums, stride, &rows, Some(6));
                let gl = GaussianLanes::load(&sc, &idx);
                let got = project_backward_lanes(&gl, &cl, &opts, &vl);
                // The portable build of the same code (the AVX one runs where the CPU has it).
                let portable = lanes(&gl, &cl, &opts, &vl);
                for l in 0..N {
                    let g: Gaussian3 = sc.gaussian(idx[l]);
                    let want = project_backward(&g, &cam, &opts, &v[l]);
                    let bits = |x: &Gaussian3Grad| {
                        let mut b: Vec<u32> =
                            x.mean.to_array().iter().map(|v| v.to_bits()).collect();
                        b.extend(
                            x.quat
                                .iter()
                                .chain(&x.scale.to_array())
                                .chain(&[x.opacity])
                                .map(|v| v.to_bits()),
                        );
                        b
                    };
                    assert_eq!(
                        bits(&got[l]),
                        bits(&want),
                        "gaussian {}: {:?} vs {:?}",
                        idx[l],
                        got[l],
                        want
                    );
                    assert_eq!(bits(&portable[l]), bits(&want), "gaussian {}", idx[l]);
                    nonzero += (want.opacity != 0.0) as usize;
                }
            }
        }
        // Not vacuous: most Gaussians get gradients.
        assert!(nonzero > 3000, "{nonzero}");
    }
}
