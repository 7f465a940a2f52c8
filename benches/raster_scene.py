"""A synthetic plant-like 3DGS scene for the rasterizer benchmarks.

Shaped like what the pipeline renders: a plant normalised to a longest side of 4 units
(docs/method.md: point-cloud preparation), made of a stem and leaves; Gaussians sit on the
surfaces with kNN-like sizes (spacing of n points over the surface area), flattened along
the surface normal as trained 3DGS leaves are, opacities spread over (0.05, 1).
Cameras: orbit at distance 4.5, elevation 15 degrees, fovy 55 (the middle of the
PlantDreamer training ranges).
"""

from __future__ import annotations

import math

import numpy as np
import torch


def _rotation_to_quat(m: np.ndarray) -> np.ndarray:
    """(w, x, y, z) quaternions of rotation matrices [N, 3, 3] (robust branch-free form)."""
    w = np.sqrt(np.maximum(0.0, 1 + m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2])) / 2
    x = np.sqrt(np.maximum(0.0, 1 + m[:, 0, 0] - m[:, 1, 1] - m[:, 2, 2])) / 2
    y = np.sqrt(np.maximum(0.0, 1 - m[:, 0, 0] + m[:, 1, 1] - m[:, 2, 2])) / 2
    z = np.sqrt(np.maximum(0.0, 1 - m[:, 0, 0] - m[:, 1, 1] + m[:, 2, 2])) / 2
    x = np.copysign(x, m[:, 2, 1] - m[:, 1, 2])
    y = np.copysign(y, m[:, 0, 2] - m[:, 2, 0])
    z = np.copysign(z, m[:, 1, 0] - m[:, 0, 1])
    return np.stack([w, x, y, z], -1)


def synthetic_plant(n: int, seed: int = 0, sh_degree: int | None = None) -> list[torch.Tensor]:
    """means, quats, scales, opacities, colors (float32) of an n-Gaussian plant."""
    rng = np.random.default_rng(seed)
    n_leaves = 40
    n_stem = n // 10
    n_leaf = n - n_stem
    # Stem: a slightly bent vertical cylinder of radius 0.04 from z = -2 to 2.
    t = rng.uniform(-2, 2, n_stem)
    phi = rng.uniform(0, 2 * math.pi, n_stem)
    stem = np.stack([0.04 * np.cos(phi) + 0.1 * np.sin(t), 0.04 * np.sin(phi), t], -1)
    stem_normal = np.stack([np.cos(phi), np.sin(phi), np.zeros(n_stem)], -1)
    # Leaves: elliptic blades (length 0.9, width 0.35) attached along the stem, curled.
    leaf_id = rng.integers(0, n_leaves, n_leaf)
    base_z = np.linspace(-1.6, 1.8, n_leaves)[leaf_id]
    yaw = (np.arange(n_leaves) * 2.4)[leaf_id]  # golden-angle phyllotaxis
    pitch = rng.uniform(0.2, 0.7, n_leaves)[leaf_id]
    u = np.sqrt(rng.uniform(0, 1, n_leaf))
    v = rng.uniform(-1, 1, n_leaf) * np.sqrt(np.maximum(0.0, 1 - (2 * u - 1) ** 2))
    along, across = 0.9 * u, 0.175 * v
    curl = 0.15 * along**2
    local = np.stack([along, across, curl], -1)
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    # Rotate the blade: pitch up about its width axis, then yaw about z.
    rot = np.zeros((n_leaf, 3, 3))
    rot[:, 0] = np.stack([cy * cp, -sy, -cy * sp], -1)
    rot[:, 1] = np.stack([sy * cp, cy, -sy * sp], -1)
    rot[:, 2] = np.stack([sp, np.zeros(n_leaf), cp], -1)
    leaves = np.einsum("nij,nj->ni", rot, local) + np.stack(
        [0.1 * np.sin(base_z), np.zeros(n_leaf), base_z], -1
    )
    means = np.concatenate([stem, leaves])
    # Surface area -> spacing -> kNN-like scale.
    area = 2 * math.pi * 0.04 * 4 + n_leaves * math.pi * 0.45 * 0.175
    spacing = math.sqrt(area / n)
    scales = spacing * np.exp(0.3 * rng.standard_normal((n, 3)))
    scales[:, 2] *= 0.15  # flat along the surface normal (local z)
    stem_rot = np.stack(
        [np.cross(stem_normal, [0, 0, 1]), np.tile([0.0, 0, 1], (n_stem, 1)), stem_normal], -1
    )
    quats = np.concatenate([_rotation_to_quat(stem_rot), _rotation_to_quat(rot)])
    opacities = 1 / (1 + np.exp(-rng.normal(1.0, 1.5, n)))
    green = np.array([0.25, 0.55, 0.15])
    if sh_degree is None:
        colors = np.clip(green + 0.1 * rng.standard_normal((n, 3)), 0, 1)
    else:
        colors = 0.2 * rng.standard_normal((n, (sh_degree + 1) ** 2, 3))
        colors[:, 0] = (green - 0.5) / 0.28209479177387814
    out = [means, quats, scales, opacities, colors]
    return [torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32)) for x in out]


def orbit_cameras(width: int, height: int, n: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
    from plantdreamer.cameras import orbit, stack

    cams = [orbit(4.5, 15.0, 30.0 + 360.0 * i / max(n, 1), 55.0, width, height) for i in range(n)]
    viewmats, ks = stack(cams)
    return torch.from_numpy(viewmats), torch.from_numpy(ks)


def dump(path: str, n: int, size: int) -> None:
    """Writes the scene and its camera as raw little-endian float32 for the Rust timing
    example (`crates/splat_core/examples/raster_timing.rs`): n, size, means, quats, scales,
    opacities, colours, viewmat, K."""
    import numpy as np

    scene = synthetic_plant(n)
    viewmats, ks = orbit_cameras(size, size)
    parts = [np.array([n, size], dtype=np.float32)]
    parts += [x.numpy().ravel() for x in scene] + [
        viewmats[0].numpy().ravel(),
        ks[0].numpy().ravel(),
    ]
    np.concatenate(parts).astype("<f4").tofile(path)


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description="Dump the benchmark scene for raster_timing.")
    parser.add_argument("--dump", required=True, metavar="FILE")
    parser.add_argument("--n", type=int, default=100_000)
    parser.add_argument("--size", type=int, default=512)
    args = parser.parse_args()
    dump(args.dump, args.n, args.size)
