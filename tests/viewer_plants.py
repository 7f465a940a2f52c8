"""A small labelled splat PLY of an L-System plant, and the check that a picture shows it.

Shared by the viewer tests and ``scripts/viewer_screenshot.py`` (the README picture).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from plantdreamer.cloud import PointCloud
from plantdreamer.io import write_ply
from plantdreamer.lsystem import generate_plant, sample_points
from plantdreamer.pipeline.model.init import init_gaussians

INRIA_ORDER = ["f_dc_0", "f_dc_1", "f_dc_2", "opacity"]
INRIA_ORDER += ["scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]


def write_labelled_plant_ply(path: Path, n: int = 5000, seed: int = 1) -> np.ndarray:
    """A bean as n opaque isotropic Gaussians, with int ``label`` and ``instance`` written
    after the INRIA properties. Returns the Gaussians' colours [n, 3]."""
    cloud = sample_points(generate_plant("bean", seed=seed), n=n, seed=seed)
    assert cloud.colors is not None
    g = init_gaussians(cloud.positions, cloud.colors, opacity=0.9)
    columns = {
        "f_dc_0": g.sh[:, 0, 0],
        "f_dc_1": g.sh[:, 0, 1],
        "f_dc_2": g.sh[:, 0, 2],
        "opacity": g.opacity_logits,
        **{f"scale_{i}": g.log_scales[:, i] for i in range(3)},
        **{f"rot_{i}": g.quats[:, i] for i in range(4)},
        "label": cloud.attributes["label"].astype(np.int32),
        "instance": cloud.attributes["instance"].astype(np.int32),
    }
    normals = np.zeros_like(g.means)
    write_ply(path, PointCloud(positions=g.means, normals=normals, attributes=columns))
    return cloud.colors.astype(np.float32)


def plant_pixels(image: np.ndarray, plant_rgbs: np.ndarray, tolerance: float = 0.1) -> np.ndarray:
    """bool [H, W]: pixels within ``tolerance`` (RGB distance, 0-1 units) of a colour of the
    plant and unlike the picture's most common colour (the background)."""
    flat = image.reshape(-1, 3).astype(np.int64)
    codes = (flat[:, 0] << 16) | (flat[:, 1] << 8) | flat[:, 2]
    colours, inverse, counts = np.unique(codes, return_inverse=True, return_counts=True)
    rgb = np.stack([colours >> 16, (colours >> 8) & 255, colours & 255], 1) / 255.0
    background = rgb[np.argmax(counts)]
    rng = np.random.default_rng(0)
    palette = plant_rgbs[rng.choice(len(plant_rgbs), size=min(256, len(plant_rgbs)), replace=False)]
    # Squared distances of each distinct colour to the palette, as |a|^2 - 2ab + |b|^2.
    d2 = (rgb**2).sum(1)[:, None] - 2.0 * rgb @ palette.T.astype(np.float64)
    d2 += (palette.astype(np.float64) ** 2).sum(1)[None, :]
    plant_like = d2.min(axis=1) < tolerance**2
    plant_like &= ((rgb - background) ** 2).sum(1) > tolerance**2
    return plant_like[inverse.reshape(-1)].reshape(image.shape[:2])


def shows_plant(
    image: np.ndarray, plant_rgbs: np.ndarray, min_fraction: float = 0.05
) -> str | None:
    """None when the picture shows the plant in the middle, else why not.

    The viewer frames the plant's bounding box at the centre of the page, so at least
    ``min_fraction`` of the central half (each axis) must be plant-coloured, and the
    plant-coloured pixels must be centred in the middle third of the picture.
    """
    mask = plant_pixels(image, plant_rgbs)
    h, w = mask.shape
    centre = mask[h // 4 : 3 * h // 4, w // 4 : 3 * w // 4]
    if centre.mean() < min_fraction:
        return f"only {centre.mean():.2%} of the centre is plant-coloured (need {min_fraction:.0%})"
    ys, xs = np.nonzero(mask)
    cy, cx = ys.mean() / h, xs.mean() / w
    if not (1 / 3 <= cy <= 2 / 3 and 1 / 3 <= cx <= 2 / 3):
        return f"the plant-coloured pixels centre at ({cx:.2f}, {cy:.2f}), not in the middle"
    return None
