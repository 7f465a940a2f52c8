"""Renders one PNG per L-System species into docs/images/ (the README's pictures): ours and
the authors' released structures (``*-released``), which the README shows side by side.

    .venv/bin/python scripts/render_species.py [--seed 1] [--out docs/images]

A painter's-algorithm renderer over matplotlib's PolyCollection: triangles are projected with
a perspective camera, sorted far to near and flat-shaded (Lambert, two-sided for leaves). It
stands in until the project's Gaussian rasterizer can render meshes.
"""

from __future__ import annotations

import argparse
import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import PolyCollection
from PIL import Image

from plantdreamer.cameras import look_at
from plantdreamer.lsystem import generate_plant, list_species


def render(mesh, path: Path, elevation: float = 22.0, azimuth: float = 35.0, size: int = 800):
    v = mesh.vertices.astype(np.float64)
    top = float(v[:, 2].max())
    target = np.array([0.0, 0.0, 0.42 * top])
    radius = max(top, float(np.abs(v[:, :2]).max()) * 1.6) * 2.1
    el, az = np.radians(elevation), np.radians(azimuth)
    eye = target + radius * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    viewmat = np.asarray(look_at(eye, target), dtype=np.float64)
    cam = v @ viewmat[:3, :3].T + viewmat[:3, 3]
    focal = 2.6
    xy = cam[:, :2] / cam[:, 2:3] * focal
    xy[:, 1] *= -1.0  # OpenCV y is down

    tri = v[mesh.faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    light = np.array([0.4, 0.3, 0.85])
    light /= np.linalg.norm(light)
    view = eye - tri.mean(axis=1)
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    facing = np.sign(np.einsum("ij,ij->i", n, view))
    n = n * facing[:, None]  # shade the side we see
    lambert = np.clip(n @ light, 0.0, 1.0)
    # Thin leaves pass light: a leaf's underside is lit by the light on its top (two-sided),
    # and undersides are paler than tops.
    leaf_back = (facing < 0) & (mesh.labels[mesh.faces[:, 0]] == 1)
    lambert[leaf_back] = 0.7 * np.abs(n[leaf_back] @ light)
    face_color = mesh.colors[mesh.faces].mean(axis=1)
    face_color[leaf_back] = 0.75 * face_color[leaf_back] + 0.25 * np.array([0.55, 0.65, 0.45])
    shade = 0.45 + 0.75 * lambert
    rgb = np.clip(face_color * shade[:, None], 0, 1)

    depth = cam[mesh.faces, 2].mean(axis=1)
    order = np.argsort(-depth)
    fig = plt.figure(figsize=(size / 100, size / 100), dpi=100)
    ax = fig.add_axes([0, 0, 1, 1])
    ax.set_facecolor((0.93, 0.93, 0.91))
    fig.patch.set_facecolor((0.93, 0.93, 0.91))
    polys = xy[mesh.faces[order]]
    ax.add_collection(
        PolyCollection(polys, facecolors=rgb[order], edgecolors=rgb[order], linewidths=0.25)
    )
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    centre, half = (lo + hi) / 2, (hi - lo).max() / 2 * 1.05
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_aspect("equal")
    ax.axis("off")
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100)
    plt.close(fig)
    # A 256-colour palette keeps the README's images ~100 kB with no visible loss.
    image = Image.open(buffer).convert("RGB")
    image.quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path("docs/images"))
    parser.add_argument("species", nargs="*", default=None)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for name in args.species or list_species():
        path = args.out / f"lsystem_{name}.png"
        # Rosettes show best from higher up.
        elevation = 38.0 if name.startswith("kale") else 22.0
        render(generate_plant(name, args.seed), path, elevation=elevation)
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
