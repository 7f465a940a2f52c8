"""Leaf masks of a generated L-System plant against its mesh: the IoU that tests/test_labels.py
asserts and scripts/leaf_mask_iou.py tabulates (docs/labels.md)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def zbuffer_leaf_mask(mesh, camera) -> np.ndarray:
    """Leaf pixels of the mesh seen by ``camera``: a plain per-face z-buffer (pixel centres,
    barycentric inside test), independent of the Gaussian rasterizer."""
    h, w = camera.height, camera.width
    uv, z = camera.project(mesh.vertices.astype(np.float64))
    depth = np.full((h, w), np.inf)
    leaf = np.zeros((h, w), bool)
    face_leaf = mesh.labels[mesh.faces[:, 0]] == 1
    px, py = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    for f, is_leaf in zip(mesh.faces, face_leaf, strict=True):
        if (z[f] <= 0).any():
            continue
        (x0, y0), (x1, y1), (x2, y2) = uv[f]
        lo_x, hi_x = int(max(0, np.floor(min(x0, x1, x2)))), int(min(w, np.ceil(max(x0, x1, x2))))
        lo_y, hi_y = int(max(0, np.floor(min(y0, y1, y2)))), int(min(h, np.ceil(max(y0, y1, y2))))
        if lo_x >= hi_x or lo_y >= hi_y:
            continue
        X, Y = px[lo_y:hi_y, lo_x:hi_x], py[lo_y:hi_y, lo_x:hi_x]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if area == 0:
            continue
        b1 = ((X - x0) * (y2 - y0) - (x2 - x0) * (Y - y0)) / area
        b2 = ((x1 - x0) * (Y - y0) - (X - x0) * (y1 - y0)) / area
        b0 = 1 - b1 - b2
        inside = (b0 >= 0) & (b1 >= 0) & (b2 >= 0)
        d = b0 * z[f[0]] + b1 * z[f[1]] + b2 * z[f[2]]
        win = inside & (d < depth[lo_y:hi_y, lo_x:hi_x])
        depth[lo_y:hi_y, lo_x:hi_x][win] = d[win]
        leaf[lo_y:hi_y, lo_x:hi_x][win] = is_leaf
    return leaf


def leaf_mask_ious(
    out_dir: Path, species: str, seed: int, against_grown_mesh: bool = False
) -> list[float]:
    """Per evaluation view of a ``generate`` output folder, the IoU of its leaf mask with the
    z-buffered leaf faces of the plant's mesh, over the whole image. With
    ``against_grown_mesh``, instead that of the mesh mask with itself grown by one pixel:
    what a silhouette one pixel too wide scores in the same views."""
    import imageio.v3 as iio

    from plantdreamer.eval.datasets import scan_transforms_json
    from plantdreamer.lsystem import generate_plant

    meta = json.loads((Path(out_dir) / "transforms.json").read_text())
    leaf_value = next(c["value"] for c in meta["semantic_classes"] if c["name"] == "leaf")
    mesh = generate_plant(species, seed)
    views = scan_transforms_json(Path(out_dir))  # the eval loader reads it as a dataset
    assert all(v.mask_path is not None for v in views)
    ious = []
    for view in views:
        mesh_leaf = zbuffer_leaf_mask(mesh, view.camera)
        ours = grown(mesh_leaf) if against_grown_mesh else iio.imread(view.mask_path) == leaf_value
        ious.append(iou(ours, mesh_leaf))
    return ious


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def grown(mask: np.ndarray) -> np.ndarray:
    """``mask`` grown by one pixel (its 3 x 3 neighbourhood)."""
    out = mask.copy()
    h, w = mask.shape
    padded = np.pad(mask, 1)
    for dy in range(3):
        for dx in range(3):
            out |= padded[dy : dy + h, dx : dx + w]
    return out
