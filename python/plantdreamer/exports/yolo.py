"""YOLO segmentation labels as Ultralytics documents them: per image a ``.txt`` whose lines
are ``class x1 y1 x2 y2 ...`` (polygon vertices normalised to [0, 1] by the image width and
height), ``labels/`` beside ``images/`` (Ultralytics finds a label by replacing the last
``/images/`` of the image path with ``/labels/``), and a ``data.yaml`` with the splits and
the class names.

One line per object, the same objects as COCO's (not its ignore regions: YOLO-seg has no
crowd or ignore label). Polygons are the outlines of an object's mask at the 0.5 level
(marching squares from contourpy, which matplotlib already brings), in pixel-edge
coordinates, traced 8-connected: pixels that touch at a corner are one piece, not two
diamonds. An object in several pieces (a leaf crossed by a stem) is one polygon: the pieces
are joined by zero-width bridges between their closest vertices along a minimum spanning
tree, as Ultralytics' ``merge_multi_segment`` joins a COCO object's polygons in its own
``convert_coco`` (there in list order). Holes are not represented. YOLO class k is the k-th
class of ``data.yaml``, in ascending category id (v - 1 for the L-System's 1..4).
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
from plantdreamer.temporaries import name_max, temporary_name

# Just under 0.5: marching squares then joins two pixels that touch only at a corner (the
# saddle's mean, 0.5, is above the level), while every edge still crosses at the pixel edge.
_LEVEL = float(np.nextafter(0.5, 0.0))


def mask_polygons(mask: np.ndarray) -> list[np.ndarray]:
    """The outer outline of each 8-connected piece of a bool mask: [M, 2] x, y vertices in
    pixel-edge coordinates (pixel (r, c) spans x in [c, c + 1]), collinear vertices removed."""
    import contourpy

    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if not len(rows):
        return []
    # Contour the object's box, not the whole frame once per object.
    y0, x0 = rows[0], cols[0]
    z = np.pad(mask[y0 : rows[-1] + 1, x0 : cols[-1] + 1].astype(np.float64), 1)
    gen = contourpy.contour_generator(z=z, fill_type="OuterOffset", corner_mask=False)
    filled: Any = gen.filled(_LEVEL, 2.0)  # OuterOffset: (points, offsets) per polygon
    points, offsets = filled[0], filled[1]
    shift = np.array([x0 - 0.5, y0 - 0.5])  # the padding, then pixel centres at +0.5
    rings = []
    for pts, offs in zip(points, offsets, strict=True):
        ring = pts[offs[0] : offs[1] - 1] + shift  # the outer ring, without its closing vertex
        rings.append(_drop_collinear(np.round(ring, 9)))
    return [r for r in rings if len(r) >= 3]


def object_polygon(mask: np.ndarray) -> np.ndarray | None:
    """One polygon for an object: its pieces' outlines joined (``join_rings``)."""
    rings = mask_polygons(mask)
    return join_rings(rings) if rings else None


def join_rings(rings: list[np.ndarray]) -> np.ndarray:
    """One closed vertex path through every ring: the largest ring is walked once around,
    and at the vertex nearest each other ring (a minimum spanning tree of the rings by their
    closest vertices) the path crosses over, walks that ring around and comes back."""
    if len(rings) == 1:
        return rings[0]
    n = len(rings)
    root = max(range(n), key=lambda i: (abs(_signed_area(rings[i])), -i))
    links: dict[tuple[int, int], list[tuple[int, int]]] = {}
    inside, outside = [root], [i for i in range(n) if i != root]
    while outside:  # Prim: attach the ring closest to the tree
        best: tuple[float, int, int, int, int] | None = None
        for i in inside:
            for j in outside:
                d = ((rings[i][:, None, :] - rings[j][None, :, :]) ** 2).sum(-1)
                va, vb = np.unravel_index(np.argmin(d), d.shape)
                if best is None or d[va, vb] < best[0]:
                    best = (float(d[va, vb]), i, int(va), j, int(vb))
        assert best is not None
        _, parent, vertex, child, entry = best
        links.setdefault((parent, vertex), []).append((child, entry))
        inside.append(child)
        outside.remove(child)

    def walk(i: int, start: int) -> list[np.ndarray]:
        ring, path = rings[i], []
        for step in range(len(ring) + 1):
            v = (start + step) % len(ring)
            path.append(ring[v])
            if step < len(ring):
                for j, b in links.get((i, v), []):
                    path += walk(j, b)
                    path.append(ring[v])
        return path

    return np.asarray(walk(root, 0)[:-1])  # the last vertex closes the path


def label_lines(objects: ViewObjects, class_index: dict[int, int]) -> list[str]:
    """The lines of one image's label file, one per object that is not an ignore region
    (``class_index``: category id -> YOLO class)."""
    h, w = objects.shape
    lines = []
    things = objects.things()
    for mask, category in zip(things.masks, things.categories, strict=True):
        polygon = object_polygon(mask)
        if polygon is None:
            continue
        xy = (polygon / np.array([w, h], dtype=np.float64)).reshape(-1)
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
    the file system has no hard links; put in place by a rename, as every write is. A
    target that already is ``source`` is left alone: renaming one link of a file over
    another link of the same file does nothing (POSIX), which would leave the temporary."""
    target.parent.mkdir(parents=True, exist_ok=True)
    if target.exists() and os.path.samefile(source, target):
        return
    limit = name_max(target.parent)
    while True:
        temporary = target.with_name(temporary_name(target.name, "link", limit))
        try:
            os.link(source, temporary)
            break
        except FileExistsError:  # the same random token: draw another
            continue
        except OSError:
            atomic.atomic_write(target, lambda tmp: shutil.copyfile(source, tmp))
            return
    os.replace(temporary, target)
    temporary.unlink(missing_ok=True)


def _signed_area(ring: np.ndarray) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _drop_collinear(ring: np.ndarray) -> np.ndarray:
    prev, nxt = np.roll(ring, 1, axis=0), np.roll(ring, -1, axis=0)
    cross = (ring[:, 0] - prev[:, 0]) * (nxt[:, 1] - ring[:, 1]) - (ring[:, 1] - prev[:, 1]) * (
        nxt[:, 0] - ring[:, 0]
    )
    return ring[cross != 0]
