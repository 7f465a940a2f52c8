"""Test helpers for the evaluation tests: a synthetic plant, a dense reference splatting
renderer, and a writer for posed datasets (transforms.json).

``render_dense`` follows the rasterizer's conventions (gsplat classic mode,
docs/rasterizer.md): OpenCV world-to-camera, pixel centres at +0.5, EWA projection with 0.3 added to
the 2D covariance, alpha = min(0.99, opacity exp(-sigma)), skipped below 1/255, front-to-back
compositing in depth order. Dense float64 numpy, SH degree 0 only: slow and obviously correct.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image

from plantdreamer.cameras import Camera
from plantdreamer.gaussians import SH_C0, Gaussians, rgb_to_sh_dc


def _rotation(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def render_dense(
    g: Gaussians, camera: Camera, background: tuple[float, float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """RGB [H, W, 3] and alpha [H, W] (float32) of SH-degree-0 Gaussians."""
    assert g.sh_degree == 0, "the reference renderer handles SH degree 0 only"
    h, w = camera.height, camera.width
    fx, fy, cx, cy = camera.K[0, 0], camera.K[1, 1], camera.K[0, 2], camera.K[1, 2]
    rot_w2c, t = camera.viewmat[:3, :3], camera.viewmat[:3, 3]
    means = g.means.astype(np.float64) @ rot_w2c.T + t
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    colour = np.zeros((h, w, 3))
    transmittance = np.ones((h, w))
    rgbs = np.maximum(SH_C0 * g.sh[:, 0].astype(np.float64) + 0.5, 0.0)
    opac = g.opacities().astype(np.float64)
    scales = g.scales().astype(np.float64)
    for n in np.argsort(means[:, 2], kind="stable"):
        x, y, z = means[n]
        if z < 0.01:
            continue
        r = _rotation(g.quats[n].astype(np.float64))
        cov = rot_w2c @ (r @ np.diag(scales[n] ** 2) @ r.T) @ rot_w2c.T
        jac = np.array([[fx / z, 0.0, -fx * x / z**2], [0.0, fy / z, -fy * y / z**2]])
        cov2 = jac @ cov @ jac.T + 0.3 * np.eye(2)
        a, b, c = np.linalg.inv(cov2)[[0, 0, 1], [0, 1, 1]]
        dx, dy = jj - (fx * x / z + cx), ii - (fy * y / z + cy)
        sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
        alpha = np.minimum(0.99, opac[n] * np.exp(-sigma))
        alpha[(alpha < 1.0 / 255.0) | (sigma < 0)] = 0.0
        colour += (transmittance * alpha)[..., None] * rgbs[n]
        transmittance *= 1.0 - alpha
    colour += transmittance[..., None] * np.asarray(background)
    return colour.astype(np.float32), (1.0 - transmittance).astype(np.float32)


def synthetic_plant(seed: int = 0) -> Gaussians:
    """A small plant-like model: a brown stem along +z and four green leaf blades.

    Stands in for an L-System plant (the L-System module lives on another branch).
    """
    rng = np.random.default_rng(seed)
    pts, cols = [], []
    z = np.linspace(0.0, 1.6, 40)
    pts.append(np.stack([0.02 * np.sin(6 * z), np.zeros_like(z), z - 0.8], axis=1))
    cols.append(np.tile([0.45, 0.3, 0.15], (len(z), 1)))
    for k in range(4):
        ang = k * np.pi / 2 + 0.3
        u = rng.uniform(0.05, 0.7, 120)
        v = rng.uniform(-1, 1, 120) * 0.25 * np.sin(np.pi * u / 0.75)
        base = -0.2 + 0.25 * k
        d = np.array([np.cos(ang), np.sin(ang), 0.0])
        side = np.array([-np.sin(ang), np.cos(ang), 0.0])
        leaf = u[:, None] * d + v[:, None] * side + (base + 0.3 * u)[:, None] * [0, 0, 1]
        pts.append(leaf)
        shade = 0.35 + 0.3 * u
        cols.append(np.stack([0.15 * shade, shade, 0.2 * shade], axis=1))
    means = np.concatenate(pts).astype(np.float32)
    rgb = np.clip(np.concatenate(cols), 0.0, 1.0)
    n = len(means)
    return Gaussians(
        means=means,
        quats=np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
        log_scales=np.full((n, 3), np.log(0.035), dtype=np.float32),
        opacity_logits=np.full(n, 3.0, dtype=np.float32),
        sh=rgb_to_sh_dc(rgb)[:, None, :],
    )


def perturbed(g: Gaussians, seed: int = 1) -> Gaussians:
    """The same model with its positions jittered and its colours shifted."""
    rng = np.random.default_rng(seed)
    rgb = np.clip(g.base_colors() + rng.normal(0.0, 0.15, g.base_colors().shape), 0, 1)
    return Gaussians(
        (g.means + rng.normal(0.0, 0.06, g.means.shape)).astype(np.float32),
        g.quats.copy(),
        g.log_scales.copy(),
        g.opacity_logits.copy(),
        rgb_to_sh_dc(rgb)[:, None, :],
    )


def to_png(rgb: np.ndarray) -> np.ndarray:
    return np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8)


def write_transforms_dataset(
    root: Path,
    g: Gaussians,
    cameras: list[Camera],
    render,
    background: tuple[float, float, float],
    rgba: bool = False,
) -> Path:
    """Render ``g`` at ``cameras`` and write a nerfstudio-style dataset in ``root``.

    rgba=False: RGB images over ``background`` + binary masks ``masks/<name>.png`` (alpha > 0.5).
    rgba=True: straight-colour RGBA images (render over black, divided by alpha), no masks.
    """
    (root / "images").mkdir(parents=True, exist_ok=True)
    (root / "masks").mkdir(exist_ok=True)
    frames = []
    for i, cam in enumerate(cameras):
        name = f"view_{i:03d}"
        if rgba:
            premult, alpha = render(g, cam, (0.0, 0.0, 0.0))
            straight = premult / np.maximum(alpha, 1e-6)[..., None]
            data = np.dstack([to_png(straight), to_png(alpha)])
            Image.fromarray(data, "RGBA").save(root / "images" / f"{name}.png")
        else:
            rgb, alpha = render(g, cam, background)
            Image.fromarray(to_png(rgb)).save(root / "images" / f"{name}.png")
            Image.fromarray(((alpha > 0.5) * 255).astype(np.uint8)).save(
                root / "masks" / f"{name}.png"
            )
        frames.append(
            {"file_path": f"images/{name}.png", "transform_matrix": cam.to_opengl_c2w().tolist()}
        )
    cam = cameras[0]
    meta = {
        "fl_x": cam.K[0, 0],
        "fl_y": cam.K[1, 1],
        "cx": cam.K[0, 2],
        "cy": cam.K[1, 2],
        "w": cam.width,
        "h": cam.height,
        "frames": frames,
    }
    (root / "transforms.json").write_text(json.dumps(meta))
    return root


def write_inria_ply(path: Path, g: Gaussians) -> Path:
    """A binary little-endian INRIA 3DGS PLY (docs/formats.md), written by hand so the
    eval tests do not depend on the project's own writer."""
    n, k = len(g), g.sh.shape[1]
    rest = g.sh[:, 1:].transpose(0, 2, 1).reshape(n, -1)  # channel-major f_rest
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(3 * (k - 1))]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    cols = [g.means, np.zeros((n, 3)), g.sh[:, 0], rest, g.opacity_logits[:, None]]
    cols += [g.log_scales, g.quats]
    data = np.concatenate([np.asarray(c, np.float32).reshape(n, -1) for c in cols], axis=1)
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    header += [f"property float {name}" for name in names] + ["end_header"]
    path.write_bytes(("\n".join(header) + "\n").encode() + data.astype("<f4").tobytes())
    return path
