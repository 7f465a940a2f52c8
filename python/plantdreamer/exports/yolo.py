"""YOLO segmentation labels as Ultralytics documents them: per image a ``.txt`` whose lines
are ``class x1 y1 x2 y2 ...`` (polygon vertices normalised to [0, 1] by the image width and
height), ``labels/`` beside ``images/`` (Ultralytics finds a label by replacing the last
``/images/`` of the image path with ``/labels/``), and a ``data.yaml`` with the splits and
the class names.

Polygons are the outlines of each object's mask at the 0.5 level (marching squares from
contourpy, which matplotlib already brings), in pixel-edge coordinates. An object cut in
pieces (a leaf crossed by a stem) is written as one line per piece, each of its class; holes
are not represented. YOLO class k is the k-th class of ``data.yaml``, in ascending pixel
value, so class pixel value v is YOLO class ``index of v`` (v - 1 for the L-System's 1..4).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from plantdreamer import atomic
from plantdreamer.exports.instances import ViewObjects


def mask_polygons(mask: np.ndarray) -> list[np.ndarray]:
    """The outer outline of each connected piece of a bool mask: [M, 2] x, y vertices in
    pixel-edge coordinates (pixel (r, c) spans x in [c, c + 1]), collinear vertices removed."""
    import contourpy

    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if not len(rows):
        return []
    # Contour the object's box, not the whole frame once per object.
    y0, x0 = rows[0], cols[0]
    z = np.pad(mask[y0 : rows[-1] + 1, x0 : cols[-1] + 1].astype(np.float64), 1)
    gen = contourpy.contour_generator(z=z, fill_type="OuterOffset", corner_mask=False)
    filled: Any = gen.filled(0.5, 2.0)  # OuterOffset: (points, offsets) per polygon
    points, offsets = filled[0], filled[1]
    shift = np.array([x0 - 0.5, y0 - 0.5])  # the padding, then pixel centres at +0.5
    rings = []
    for pts, offs in zip(points, offsets, strict=True):
        ring = pts[offs[0] : offs[1] - 1] + shift  # the outer ring, without its closing vertex
        rings.append(_drop_collinear(ring))
    return [r for r in rings if len(r) >= 3]


def label_lines(objects: ViewObjects, class_index: dict[int, int]) -> list[str]:
    """The lines of one image's label file (``class_index``: pixel value -> YOLO class)."""
    h, w = objects.shape
    lines = []
    for mask, category in zip(objects.masks, objects.categories, strict=True):
        for ring in mask_polygons(mask):
            xy = (ring / np.array([w, h], dtype=np.float64)).reshape(-1)
            coords = " ".join(f"{v:.6f}" for v in xy)
            lines.append(f"{class_index[int(category)]} {coords}")
    return lines


def class_index(names: dict[int, str]) -> dict[int, int]:
    """Pixel value -> YOLO class: the values in ascending order, from 0."""
    return {v: i for i, v in enumerate(sorted(names))}


def write_labels(path: Path, lines: list[str]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic.write_text(path, "".join(line + "\n" for line in lines))


def write_data_yaml(path: Path, splits: dict[str, str], names: dict[int, str]) -> None:
    """``data.yaml`` without a ``path`` key: Ultralytics then resolves the split folders
    against the yaml's own folder, so the dataset can move."""
    lines = [f"{split}: {json.dumps(folder)}" for split, folder in splits.items()]
    lines.append(f"nc: {len(names)}")
    lines.append("names:")
    lines += [f"  {i}: {json.dumps(names[v])}" for v, i in class_index(names).items()]
    atomic.write_text(path, "\n".join(lines) + "\n")


def link_image(source: Path, target: Path) -> None:
    """``target`` as a hard link to ``source`` (no second copy on disk), or a copy where
    the file system has no hard links; put in place by a rename, as every write is."""
    target.parent.mkdir(parents=True, exist_ok=True)
    temporary = target.with_name(f".{target.name}.link")
    temporary.unlink(missing_ok=True)
    try:
        os.link(source, temporary)
    except OSError:
        atomic.atomic_write(target, lambda tmp: shutil.copyfile(source, tmp))
        return
    os.replace(temporary, target)


def _drop_collinear(ring: np.ndarray) -> np.ndarray:
    prev, nxt = np.roll(ring, 1, axis=0), np.roll(ring, -1, axis=0)
    cross = (ring[:, 0] - prev[:, 0]) * (nxt[:, 1] - ring[:, 1]) - (ring[:, 1] - prev[:, 1]) * (
        nxt[:, 0] - ring[:, 0]
    )
    return ring[cross != 0]
