"""Dense float64 reference rasterizer (tests only): gsplat 1.5 "classic" rules, no tiles.

Every pixel composites every Gaussian that survives the per-Gaussian culls, in depth order,
with alpha = min(0.99, o exp(-sigma)), skipping alpha < 1/255 and stopping before the
Gaussian that would bring T to <= t_min. Written for clarity, vectorised over pixels and
looped over Gaussians; differentiable by torch autograd. Also: SH by the direct formulas.
"""

from __future__ import annotations

import math

import torch

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
SH_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def sh_basis(degree: int, d: torch.Tensor) -> torch.Tensor:
    """Real SH basis [..., (degree+1)^2] at unit directions d [..., 3] (3DGS convention)."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    out = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out += [
            SH_C2[0] * x * y,
            SH_C2[1] * y * z,
            SH_C2[2] * (2 * zz - xx - yy),
            SH_C2[3] * x * z,
            SH_C2[4] * (xx - yy),
        ]
    if degree >= 3:
        out += [
            SH_C3[0] * y * (3 * xx - yy),
            SH_C3[1] * x * y * z,
            SH_C3[2] * y * (4 * zz - xx - yy),
            SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
            SH_C3[4] * x * (4 * zz - xx - yy),
            SH_C3[5] * z * (xx - yy),
            SH_C3[6] * x * (xx - 3 * yy),
        ]
    return torch.stack(out, dim=-1)


def sh_eval(degree: int, coeffs: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """SH value before +0.5: coeffs [N, K, 3], dirs [N, 3] (any length, zero allowed)."""
    norm = dirs.norm(dim=-1, keepdim=True)
    d = torch.where(norm > 0, dirs / norm.clamp_min(1e-300), torch.zeros_like(dirs))
    b = sh_basis(degree, d)
    return (b[..., None] * coeffs[:, : b.shape[-1]]).sum(-2)


def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    w, x, y, z = (q / q.norm(dim=-1, keepdim=True)).unbind(-1)
    return torch.stack(
        [
            torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def project(means, quats, scales, opacities, viewmat, K, width, height, near, far, eps2d, aa):
    """Per-Gaussian 2D centre, conic (a, b, c), depth, blend opacity and a keep mask."""
    R, t = viewmat[:3, :3], viewmat[:3, 3]
    p = means @ R.T + t
    x, y, z = p.unbind(-1)
    rot = quat_to_rotmat(quats)
    m = rot * scales[:, None, :]
    cov_c = R @ (m @ m.transpose(-1, -2)) @ R.T
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    tan_fovx, tan_fovy = 0.5 * width / fx, 0.5 * height / fy
    lim_xp, lim_xn = (width - cx) / fx + 0.3 * tan_fovx, cx / fx + 0.3 * tan_fovx
    lim_yp, lim_yn = (height - cy) / fy + 0.3 * tan_fovy, cy / fy + 0.3 * tan_fovy
    tx = z * torch.clamp(x / z, -lim_xn, lim_xp)
    ty = z * torch.clamp(y / z, -lim_yn, lim_yp)
    zero = torch.zeros_like(z)
    J = torch.stack(
        [
            torch.stack([fx / z, zero, -fx * tx / z**2], -1),
            torch.stack([zero, fy / z, -fy * ty / z**2], -1),
        ],
        -2,
    )
    cov2d = J @ cov_c @ J.transpose(-1, -2)
    a0, b, c0 = cov2d[:, 0, 0], cov2d[:, 0, 1], cov2d[:, 1, 1]
    det0 = a0 * c0 - b * b
    a, c = a0 + eps2d, c0 + eps2d
    det = a * c - b * b
    conic = torch.stack([c / det, -b / det, a / det], -1)
    opac = opacities * torch.sqrt(torch.clamp_min(det0 / det, 0.0)) if aa else opacities
    xy = torch.stack([fx * x / z + cx, fy * y / z + cy], -1)
    keep = (z >= near) & (z <= far) & (det > 0) & (opac >= ALPHA_MIN)
    return xy, conic, z, opac, keep


def render(
    means,
    quats,
    scales,
    opacities,
    colors,
    viewmat,
    K,
    width,
    height,
    near=0.01,
    far=1e10,
    eps2d=0.3,
    sh_degree=None,
    with_color=True,
    with_depth=False,
    antialiased=False,
    t_min=1e-4,
    means2d_offset=None,
):
    """One camera. Returns features [H, W, ch] (no background) and alpha [H, W].

    ``means2d_offset`` [N, 2] (zeros) is added to the projected centres; its gradient is the
    gradient w.r.t. the 2D means.
    """
    xy, conic, depth, opac, keep = project(
        means, quats, scales, opacities, viewmat, K, width, height, near, far, eps2d, antialiased
    )
    if means2d_offset is not None:
        xy = xy + means2d_offset
    feats = []
    if with_color:
        if sh_degree is None:
            feats.append(colors)
        else:
            centre = -viewmat[:3, :3].T @ viewmat[:3, 3]
            feats.append(torch.clamp_min(sh_eval(sh_degree, colors, means - centre) + 0.5, 0.0))
    if with_depth:
        feats.append(depth[:, None])
    f = torch.cat(feats, -1)
    order = [i for i in torch.argsort(depth.detach(), stable=True).tolist() if keep[i]]

    jj, ii = torch.meshgrid(
        torch.arange(width, dtype=means.dtype),
        torch.arange(height, dtype=means.dtype),
        indexing="xy",
    )
    px, py = (jj + 0.5).reshape(-1), (ii + 0.5).reshape(-1)
    T = torch.ones_like(px)
    out = torch.zeros(px.shape[0], f.shape[1], dtype=means.dtype)
    done = torch.zeros_like(px, dtype=torch.bool)
    for g in order:
        dx, dy = xy[g, 0] - px, xy[g, 1] - py
        sigma = 0.5 * (conic[g, 0] * dx * dx + conic[g, 2] * dy * dy) + conic[g, 1] * dx * dy
        alpha = torch.clamp(opac[g] * torch.exp(-sigma), max=ALPHA_MAX)
        use = (sigma >= 0) & (alpha >= ALPHA_MIN) & ~done
        next_T = T * (1 - alpha)
        stop = use & (next_T <= t_min)
        done = done | stop
        use = use & ~stop
        w = torch.where(use, alpha * T, torch.zeros_like(T))
        out = out + w[:, None] * f[g]
        T = torch.where(use, next_T, T)
    return out.reshape(height, width, -1), (1 - T).reshape(height, width)


def closed_form_single(mean2d, cov2d, opacity, color, width, height):
    """Image of one 2D Gaussian splat (blurred covariance given), float64."""
    jj, ii = torch.meshgrid(
        torch.arange(width, dtype=torch.float64),
        torch.arange(height, dtype=torch.float64),
        indexing="xy",
    )
    d = torch.stack([mean2d[0] - (jj + 0.5), mean2d[1] - (ii + 0.5)], -1)
    inv = torch.linalg.inv(cov2d)
    sigma = 0.5 * torch.einsum("hwi,ij,hwj->hw", d, inv, d)
    alpha = torch.clamp(opacity * torch.exp(-sigma), max=ALPHA_MAX)
    alpha = torch.where(alpha >= ALPHA_MIN, alpha, torch.zeros_like(alpha))
    return alpha[..., None] * torch.as_tensor(color, dtype=torch.float64), alpha


def fov_intrinsics(fovy_deg, width, height):
    f = 0.5 * height / math.tan(math.radians(fovy_deg) / 2)
    return torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], dtype=torch.float64)


def plant_scene(seed: int, n: int = 300, sh_degree: int | None = None, spread: float = 0.7):
    """A random plant-like scene (float32): a stem of small elongated Gaussians plus leaf
    clusters of flat, anisotropic, overlapping Gaussians around it."""
    g = torch.Generator().manual_seed(seed)
    n_stem = n // 5
    n_leaf = n - n_stem
    t = torch.rand(n_stem, generator=g)
    stem = torch.stack(
        [0.05 * torch.sin(6 * t), 0.05 * torch.cos(5 * t), 2 * spread * (t - 0.5)], -1
    )
    n_clusters = 6
    centres = (torch.rand(n_clusters, 3, generator=g) - 0.5) * 2 * spread
    which = torch.randint(0, n_clusters, (n_leaf,), generator=g)
    leaves = centres[which] + 0.12 * spread * torch.randn(n_leaf, 3, generator=g)
    means = torch.cat([stem, leaves])
    scales = torch.cat(
        [
            torch.tensor([0.01, 0.01, 0.04]) * torch.exp(0.3 * torch.randn(n_stem, 3, generator=g)),
            torch.tensor([0.05, 0.025, 0.003])
            * torch.exp(0.5 * torch.randn(n_leaf, 3, generator=g)),
        ]
    )
    quats = torch.randn(n, 4, generator=g)
    opacities = torch.sigmoid(2.0 * torch.randn(n, generator=g) + 1.0)
    if sh_degree is None:
        colors = torch.rand(n, 3, generator=g) * torch.tensor([0.5, 1.0, 0.4])
    else:
        k = (sh_degree + 1) ** 2
        colors = 0.4 * torch.randn(n, k, 3, generator=g)
    return [x.float().contiguous() for x in (means, quats, scales, opacities, colors)]


def scene_cameras(width: int, height: int, n: int = 1, distance: float = 1.8, fovy: float = 50.0):
    """``n`` orbit cameras looking at the origin: viewmats [n, 4, 4], Ks [n, 3, 3] float32."""
    from plantdreamer.cameras import orbit, stack

    cams = [
        orbit(distance, 15.0 + 20.0 * i, 30.0 + 70.0 * i, fovy, width, height) for i in range(n)
    ]
    viewmats, ks = stack(cams)
    return torch.from_numpy(viewmats), torch.from_numpy(ks)
