"""The 8-connected pieces of a bool mask (pixels touching by an edge or a corner are one
piece), as object outlines and YOLO polygons count them.

Union-find over the pairs of neighbouring mask pixels, vectorised: every round hooks each
root to the smallest root beside it, then compresses paths by pointer jumping, until no
neighbouring pair has two roots. Roots only ever point to smaller indices, so there are no
cycles, and a piece's root is its first pixel in raster order.
"""

from __future__ import annotations

import numpy as np

# The four "forward" neighbours of a pixel (right, down-left, down, down-right): with their
# mirror images they are its 8 neighbours, each pair counted once.
_FORWARD = ((0, 1), (1, -1), (1, 0), (1, 1))


def label_pieces(mask: np.ndarray) -> tuple[np.ndarray, int]:
    """int32 labels (0 outside the mask, pieces 1..n in raster order of their first pixel)
    and n."""
    mask = np.asarray(mask, dtype=bool)
    h, w = mask.shape
    labels = np.zeros((h, w), dtype=np.int32)
    pixels = np.flatnonzero(mask)
    if not pixels.size:
        return labels, 0
    a, b = _neighbour_pairs(mask)
    parent = np.arange(h * w, dtype=np.int64)
    while a.size:
        ra, rb = parent[a], parent[b]
        apart = ra != rb
        if not apart.any():
            break
        ra, rb = ra[apart], rb[apart]
        np.minimum.at(parent, np.maximum(ra, rb), np.minimum(ra, rb))
        while True:  # pointer jumping: every pixel points to its root
            jumped = parent[parent]
            if np.array_equal(jumped, parent):
                break
            parent = jumped
        a, b = a[apart], b[apart]
    roots, index = np.unique(parent[pixels], return_inverse=True)
    labels.reshape(-1)[pixels] = index.astype(np.int32) + 1
    return labels, len(roots)


def _neighbour_pairs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices (a, b) of every pair of 8-neighbouring mask pixels, a before b."""
    h, w = mask.shape
    index = np.arange(h * w, dtype=np.int64).reshape(h, w)
    firsts, seconds = [], []
    for dy, dx in _FORWARD:
        x0, x1 = max(0, -dx), w - max(0, dx)
        here = mask[: h - dy, x0:x1] & mask[dy:, x0 + dx : x1 + dx]
        firsts.append(index[: h - dy, x0:x1][here])
        seconds.append(index[dy:, x0 + dx : x1 + dx][here])
    return np.concatenate(firsts), np.concatenate(seconds)
