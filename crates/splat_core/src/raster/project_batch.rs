//! The forward projection of `project::project`, eight Gaussians at a time.
//!
//! The per-Gaussian code is a long chain of scalar products, divisions and square roots
//! (~200 cycles); here the same formulas run on `Lanes` of eight values, which the compiler
//! turns into SIMD instructions on any x86-64 (SSE2) or AArch64 CPU. Two shortcuts save
//! work without changing the rules: the rotation comes from the unnormalised quaternion
//! scaled by 2 / |q|^2 (no square root, one division), and only the 2x2 image-plane
//! covariance is formed, as T T^T with T = J W and W = R_cam R S (not the full 3x3
//! camera-space covariance). Rounding therefore differs from `project::project` in the
//! last bits; `tests` holds the two to 1e-5 relative and to the same culling decisions.
//! `project::project` stays the reference, and the backward pass recomputes its
//! intermediates from it.

use rayon::prelude::*;

use super::batch_lanes::{Lanes, N};
use super::camera::Camera;
use super::options::{RasterOptions, ALPHA_MIN};
use super::project::{ceil_nonneg, extent_for_contour, Splat, QUAT_NORM2_MIN};
use super::scene::Scene;
use crate::memory::try_filled;
use crate::CoreResult;

/// A 3-vector of lanes.
type V3 = [Lanes; 3];

/// Projects every Gaussian of the scene for one camera (`Splat::default()` = culled). A
/// Gaussian whose colour holds NaN or Inf is culled too: it would poison every pixel
/// behind it.
pub fn project_all(scene: &Scene, cam: &Camera, opts: &RasterOptions) -> CoreResult<Vec<Splat>> {
    project_all_by(scene, cam, opts, |block| block.run())
}

/// `project_all` with the blocks projected by `run` (which calls `Block::run`, for example
/// from a function compiled for a wider vector ISA).
pub(super) fn project_all_by(
    scene: &Scene,
    cam: &Camera,
    opts: &RasterOptions,
    run: impl Fn(Block) + Sync,
) -> CoreResult<Vec<Splat>> {
    let mut splats = try_filled(scene.n, Splat::default())?;
    let cl = CameraLanes::new(cam);
    // Blocks of many lane groups: one rayon task per block, not per eight Gaussians.
    splats
        .par_chunks_mut(Block::LEN)
        .enumerate()
        .for_each(|(b, out)| {
            run(Block {
                scene,
                first: b * Block::LEN,
                cam,
                cl: &cl,
                opts,
                out,
            })
        });
    Ok(splats)
}

/// A block of consecutive Gaussians to project.
pub(super) struct Block<'a> {
    scene: &'a Scene,
    first: usize,
    cam: &'a Camera,
    cl: &'a CameraLanes,
    opts: &'a RasterOptions,
    out: &'a mut [Splat],
}

impl Block<'_> {
    const LEN: usize = 32 * N;

    #[inline(always)]
    pub(super) fn run(self) {
        for (k, out) in self.out.chunks_mut(N).enumerate() {
            let first = self.first + k * N;
            project_lanes(self.scene, first, self.cam, self.cl, self.opts, out);
        }
    }
}

/// Camera quantities every lane group uses.
struct CameraLanes {
    rot: [[f32; 3]; 3],
    trans: [f32; 3],
    /// Jacobian clamp limits (right, left, down, up) of x/z and y/z.
    lim: [f32; 4],
}

impl CameraLanes {
    fn new(cam: &Camera) -> Self {
        // rot[i][j]: row i, column j of the world-to-camera rotation.
        let r = cam.rot.transpose().to_cols_array_2d();
        Self {
            rot: r,
            trans: cam.trans.to_array(),
            lim: cam.jacobian_limits(),
        }
    }
}

/// Projects Gaussians first .. first + out.len() (at most eight) into `out`.
#[inline(always)]
fn project_lanes(
    scene: &Scene,
    first: usize,
    cam: &Camera,
    cl: &CameraLanes,
    opts: &RasterOptions,
    out: &mut [Splat],
) {
    let m = out.len();
    // Lanes past the scene's end repeat its last Gaussian; their results are dropped.
    let idx = |l: usize| first + l.min(m - 1);
    let load = |v: &[f32], w: usize, c: usize| Lanes(std::array::from_fn(|l| v[idx(l) * w + c]));
    let mean: V3 = std::array::from_fn(|c| load(&scene.means, 3, c));
    let scale: V3 = std::array::from_fn(|c| load(&scene.scales, 3, c));
    let [w, x, y, z] = std::array::from_fn(|c| load(&scene.quats, 4, c));

    // Camera-space centre.
    let p: V3 = std::array::from_fn(|i| {
        mean[0] * Lanes::splat(cl.rot[i][0])
            + mean[1] * Lanes::splat(cl.rot[i][1])
            + mean[2] * Lanes::splat(cl.rot[i][2])
            + Lanes::splat(cl.trans[i])
    });

    // Rotation of the unnormalised quaternion: R = I + (2 / |q|^2) (...).
    let n2 = w * w + x * x + y * y + z * z;
    let s = Lanes::splat(2.0) / n2;
    let one = Lanes::splat(1.0);
    let (xx, yy, zz) = (x * x, y * y, z * z);
    let (xy, xz, yz) = (x * y, x * z, y * z);
    let (wx, wy, wz) = (w * x, w * y, w * z);
    // rq[i][j]: row i, column j.
    let rq: [V3; 3] = [
        [one - s * (yy + zz), s * (xy - wz), s * (xz + wy)],
        [s * (xy + wz), one - s * (xx + zz), s * (yz - wx)],
        [s * (xz - wy), s * (yz + wx), one - s * (xx + yy)],
    ];
    // W = R_cam R S: the camera-space covariance is W W^T.
    let wm: [V3; 3] = std::array::from_fn(|i| {
        std::array::from_fn(|j| {
            (Lanes::splat(cl.rot[i][0]) * rq[0][j]
                + Lanes::splat(cl.rot[i][1]) * rq[1][j]
                + Lanes::splat(cl.rot[i][2]) * rq[2][j])
                * scale[j]
        })
    });

    // EWA Jacobian rows (fx/z, 0, -fx tx/z^2) and (0, fy/z, -fy ty/z^2), x/z and y/z
    // clamped to the limits.
    let [lxp, lxn, lyp, lyn] = cl.lim;
    let rz = one / p[2];
    let u = (p[0] * rz).map(|v| v.clamp(-lxn, lxp));
    let v = (p[1] * rz).map(|v| v.clamp(-lyn, lyp));
    let (fx, fy) = (Lanes::splat(cam.fx), Lanes::splat(cam.fy));
    let (j00, j02) = (fx * rz, -(fx * (p[2] * u) * rz * rz));
    let (j11, j12) = (fy * rz, -(fy * (p[2] * v) * rz * rz));
    // T = J W (2 x 3), the 2D covariance T T^T.
    let t0: V3 = std::array::from_fn(|k| j00 * wm[0][k] + j02 * wm[2][k]);
    let t1: V3 = std::array::from_fn(|k| j11 * wm[1][k] + j12 * wm[2][k]);
    let dot = |a: &V3, b: &V3| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let (a0, b, c0) = (dot(&t0, &t0), dot(&t0, &t1), dot(&t1, &t1));
    let eps = Lanes::splat(opts.eps2d);
    let (a, c) = (a0 + eps, c0 + eps);
    let det = a * c - b * b;
    let inv_det = one / det;
    let conic = [c * inv_det, -b * inv_det, a * inv_det];
    let compensation = if opts.antialiased {
        // det(T T^T) = |T0 x T1|^2 (Lagrange's identity), free of the cancellation in
        // a0 c0 - b^2 for thin splats seen edge-on.
        let cross = [
            t0[1] * t1[2] - t0[2] * t1[1],
            t0[2] * t1[0] - t0[0] * t1[2],
            t0[0] * t1[1] - t0[1] * t1[0],
        ];
        (dot(&cross, &cross) * inv_det).map(|v| v.sqrt())
    } else {
        one
    };
    let opacity = load(&scene.opacities, 1, 0) * compensation;
    let xy = [
        fx * p[0] * rz + Lanes::splat(cam.cx),
        fy * p[1] * rz + Lanes::splat(cam.cy),
    ];
    // Footprint: alpha = 1/255 contour, extent in sigmas, gsplat's ceiled radii, box
    // half-sizes (see `project::project`). ln stays per lane (no SIMD ln in std).
    let qmax = opacity.map(|o| 2.0 * (o / ALPHA_MIN).ln().max(0.0));
    let extent = qmax.map(|q| extent_for_contour(opts.footprint, q));
    let radius = [
        (extent * a.sqrt()).map(ceil_nonneg),
        (extent * c.sqrt()).map(ceil_nonneg),
    ];
    let half = [(qmax * a).sqrt(), (qmax * c).sqrt()];
    // 0 x is NaN exactly when x is NaN or infinite (else +-0): one sum flags every input.
    let mut finite_probe = mean
        .iter()
        .chain(&scale)
        .chain(&[w, x, y, z, load(&scene.opacities, 1, 0)])
        .fold(Lanes::splat(0.0), |acc, v| acc + *v * Lanes::splat(0.0));
    let cw = scene.color_width();
    for ci in 0..cw {
        let v = load(&scene.colors, cw, ci);
        finite_probe = finite_probe + v * Lanes::splat(0.0);
    }

    let (width, height) = (cam.width as f32, cam.height as f32);
    for (l, o) in out.iter_mut().enumerate() {
        let lane = |v: Lanes| v.0[l];
        let (z, n2, det) = (lane(p[2]), lane(n2), lane(det));
        let conic = conic.map(lane);
        let (xy, radius) = (xy.map(lane), radius.map(lane));
        let valid = lane(finite_probe) == 0.0
            && (z >= opts.near_plane && z <= opts.far_plane)
            && (n2.is_finite() && n2 >= QUAT_NORM2_MIN)
            && (det.is_finite() && det > 0.0)
            && conic.iter().all(|v| v.is_finite())
            && lane(opacity) >= ALPHA_MIN
            && (radius[0] > 0.0 || radius[1] > 0.0)
            && xy[0] + radius[0] > 0.0
            && xy[0] - radius[0] < width
            && xy[1] + radius[1] > 0.0
            && xy[1] - radius[1] < height;
        *o = if valid {
            Splat {
                xy,
                conic,
                opacity: lane(opacity),
                depth: z,
                radius,
                extent: lane(extent),
                half: half.map(lane),
            }
        } else {
            Splat::default()
        };
    }
}

#[cfg(test)]
mod tests {
    use super::super::options::Footprint;
    use super::super::project::{project, Gaussian3};
    use super::super::test_gaussians::{GaussianLists, DEGENERATE, SUB_PIXEL};
    use super::*;
    use crate::test_rng::Lcg;

    fn camera(w: u32, h: u32) -> Camera {
        // Looking down +z from z = -4, slightly rotated about y.
        let (s, c) = (0.3f32.sin(), 0.3f32.cos());
        let view = [
            c, 0.0, s, 0.2, //
            0.0, 1.0, 0.0, -0.1, //
            -s, 0.0, c, 4.0, //
            0.0, 0.0, 0.0, 1.0,
        ];
        let k = [
            200.0,
            0.0,
            w as f32 / 2.0,
            0.0,
            210.0,
            h as f32 / 2.0,
            0.0,
            0.0,
            1.0,
        ];
        Camera::from_matrices(&view, &k, w, h).unwrap()
    }

    /// Random Gaussians plus the degenerate ones the culling rules are about.
    fn scene(n: usize, seed: u64) -> Scene {
        let mut r = Lcg::new(seed);
        let mut gaussians = GaussianLists::default();
        for _ in 0..n {
            let mean = [
                4.0 * r.uniform() - 2.0,
                4.0 * r.uniform() - 2.0,
                6.0 * r.uniform() - 3.0,
            ];
            let quat = [0; 4].map(|_| r.uniform() - 0.5);
            let base = 10f32.powf(-3.0 + 2.5 * r.uniform());
            let scales = [
                base,
                base * (0.05 + r.uniform()),
                base * (0.05 + r.uniform()),
            ];
            gaussians.push((mean, quat, scales, r.uniform()));
        }
        DEGENERATE.into_iter().for_each(|g| gaussians.push(g));
        gaussians.push(([0.0; 3], [1.0, 0.0, 0.0, 0.0], [0.1; 3], 1e-3)); // below 1/255
        gaussians.push(([50.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.01; 3], 0.9)); // off screen
        gaussians.push(SUB_PIXEL);
        let mut colors = vec![0.5f32; gaussians.len() * 3];
        colors[3 * 7] = f32::NAN; // a non-finite colour culls its Gaussian
        gaussians.scene(&colors)
    }

    /// `project`'s formulas in float64, straight from the definitions: Sigma = R S S^T R^T
    /// in camera space, J Sigma J^T + eps2d. Returns (xy, conic, opacity, depth, extent,
    /// half, the 2D standard deviations).
    fn reference(g: &Gaussian3, cam: &Camera, opts: &RasterOptions) -> [f64; 12] {
        use glam::{DMat3, DVec3};
        let rot = DMat3::from_cols_array(&cam.rot.to_cols_array().map(|v| v as f64));
        let p = rot * g.mean.as_dvec3() + cam.trans.as_dvec3();
        let q = g.quat.map(|v| v as f64);
        let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        let [w, x, y, z] = q.map(|v| v / n);
        let r = DMat3::from_cols(
            DVec3::new(
                1.0 - 2.0 * (y * y + z * z),
                2.0 * (x * y + w * z),
                2.0 * (x * z - w * y),
            ),
            DVec3::new(
                2.0 * (x * y - w * z),
                1.0 - 2.0 * (x * x + z * z),
                2.0 * (y * z + w * x),
            ),
            DVec3::new(
                2.0 * (x * z + w * y),
                2.0 * (y * z - w * x),
                1.0 - 2.0 * (x * x + y * y),
            ),
        );
        let m = r * DMat3::from_diagonal(g.scale.as_dvec3());
        let cov = rot * m * m.transpose() * rot.transpose();
        let l = cam.jacobian_limits().map(|v| v as f64);
        let (fx, fy) = (cam.fx as f64, cam.fy as f64);
        let tx = p.z * (p.x / p.z).clamp(-l[1], l[0]);
        let ty = p.z * (p.y / p.z).clamp(-l[3], l[2]);
        let j0 = DVec3::new(fx / p.z, 0.0, -fx * tx / (p.z * p.z));
        let j1 = DVec3::new(0.0, fy / p.z, -fy * ty / (p.z * p.z));
        let (a0, b, c0) = (j0.dot(cov * j0), j0.dot(cov * j1), j1.dot(cov * j1));
        let eps = opts.eps2d as f64;
        let (a, c) = (a0 + eps, c0 + eps);
        let det = a * c - b * b;
        let comp = if opts.antialiased {
            ((a0 * c0 - b * b) / det).max(0.0).sqrt()
        } else {
            1.0
        };
        let opacity = g.opacity as f64 * comp;
        let qmax = 2.0 * (opacity * 255.0).ln().max(0.0);
        let extent = match opts.footprint {
            Footprint::OpacityAware => qmax.sqrt().min(3.33),
            Footprint::Sigma(k) => k as f64,
        };
        [
            fx * p.x / p.z + cam.cx as f64,
            fy * p.y / p.z + cam.cy as f64,
            c / det,
            -b / det,
            a / det,
            opacity,
            p.z,
            extent,
            (qmax * a).sqrt(),
            (qmax * c).sqrt(),
            a.sqrt(),
            c.sqrt(),
        ]
    }

    /// The AVX2 build of the lane code (`project_avx2`) gives the baseline build's bits.
    #[test]
    fn avx2_build_gives_the_same_bits() {
        let bits = |s: &Splat| {
            let v = [
                s.xy[0], s.xy[1], s.conic[0], s.conic[1], s.conic[2], s.opacity,
            ];
            let w = [
                s.depth,
                s.radius[0],
                s.radius[1],
                s.extent,
                s.half[0],
                s.half[1],
            ];
            v.into_iter().chain(w).map(f32::to_bits).collect::<Vec<_>>()
        };
        let cam = camera(320, 240);
        for (antialiased, footprint) in [
            (false, Footprint::OpacityAware),
            (true, Footprint::OpacityAware),
            (true, Footprint::Sigma(3.0)),
        ] {
            let opts = RasterOptions {
                antialiased,
                footprint,
                ..Default::default()
            };
            let sc = scene(4001, 5);
            let plain = project_all(&sc, &cam, &opts).unwrap();
            let wide = super::super::project_avx2::project_all(&sc, &cam, &opts).unwrap();
            assert!(plain.iter().filter(|s| s.visible()).count() > 1000);
            for (i, (a, b)) in plain.iter().zip(&wide).enumerate() {
                assert_eq!(bits(a), bits(b), "Gaussian {i}");
            }
        }
    }

    #[test]
    fn agrees_with_float64_and_culls_like_the_per_gaussian_projection() {
        for (seed, n, antialiased, footprint) in [
            (1, 3000, false, Footprint::OpacityAware),
            (2, 3001, true, Footprint::OpacityAware),
            (3, 5, false, Footprint::Sigma(3.0)),
        ] {
            let sc = scene(n, seed);
            let cam = camera(320, 240);
            let opts = RasterOptions {
                antialiased,
                footprint,
                ..Default::default()
            };
            let got = project_all(&sc, &cam, &opts).unwrap();
            let mut visible = 0;
            for (i, g) in got.iter().enumerate() {
                let color_ok = sc.color_row(i).iter().all(|v| v.is_finite());
                let want = if color_ok {
                    project(&sc.gaussian(i), &cam, &opts)
                } else {
                    Splat::default()
                };
                assert_eq!(
                    g.visible(),
                    want.visible(),
                    "gaussian {i}: {g:?} vs {want:?}"
                );
                if !want.visible() {
                    assert_eq!(*g, Splat::default());
                    continue;
                }
                visible += 1;
                let r = reference(&sc.gaussian(i), &cam, &opts);
                let v = [
                    g.xy[0], g.xy[1], g.conic[0], g.conic[1], g.conic[2], g.opacity, g.depth,
                    g.extent, g.half[0], g.half[1],
                ];
                // Scale of each value: the image width for xy, the conic's size for its
                // entries, the largest extent (3.33 sigma) for extent and half-sizes, whose
                // relative error grows without bound as opacity nears 1/255 (ln(255 o) -> 0).
                let conic_scale = r[2].abs().max(r[4].abs());
                for (k, (&a, &b)) in v.iter().zip(&r).enumerate() {
                    let scale = match k {
                        0 | 1 => cam.width as f64,
                        2..=4 => conic_scale,
                        7 => 3.33,
                        8 | 9 => 3.33 * r[k + 2],
                        _ => b.abs(),
                    };
                    let err = (a as f64 - b).abs() / scale;
                    assert!(
                        err < 1e-5,
                        "gaussian {i} value {k}: {a} vs {b} (rel {err:e})"
                    );
                }
                // ceil of values that differ in the last bits may differ by one pixel.
                for k in 0..2 {
                    assert!((g.radius[k] - want.radius[k]).abs() <= 1.0);
                }
            }
            // Not vacuous: most random Gaussians are in view.
            assert!(visible > n / 3, "only {visible} of {n} visible");
        }
    }
}
