"""How much of each visible leaf a view shows: the leaf's pixels in the view's instance map
against its pixels when its Gaussians are rendered alone from the same camera.

A leaf alone is its own Gaussians through the rasterizer, with the label renders'
settings, and its silhouette the pixels where their accumulated alpha reaches the label
maps' threshold (0.5). Leaves are not rendered one by one: the tiles (16 px, the label
renders') each leaf's footprints can touch are painted as the rasterizer bins them, and
leaves whose tile sets do not meet share one render (greedy colouring, as the label
maps' instance channels are shared), for no pixel of one tile ever sees another leaf's
Gaussians: each render's alpha in a leaf's tiles is that leaf's alone. A render covers
the whole tiles around its leaves only (the principal point moved by the window's
corner, so the tiles are the full view's). All renders of a view are one
``rasterization_many`` call. A leaf's figures are ``alone`` (its silhouette's pixels) and
``visible`` (those of them that the view's instance map gives it); its visible fraction is
visible / alone.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from plantdreamer.cameras import Camera, stack

ALPHA_THRESHOLD = 0.5  # the label maps' foreground threshold (pipeline.ground_truth)
TILE = 16  # the label renders' tile size
# The renders' rasterizer threads: one pool of one thread, which runs beside the run's own
# renders (ViewRecorder measures a view while the run writes it and renders the next)
# rather than queueing in their pool.
OWN_THREADS = 1


@dataclass(frozen=True)
class SplatArrays:
    """Activated Gaussians (float32 tensors, the scene frame) and each one's instance id
    (-1: none) and whether it is a leaf's."""

    means: torch.Tensor
    quats: torch.Tensor
    scales: torch.Tensor
    opacities: torch.Tensor
    instances: np.ndarray
    leaf: np.ndarray


class LeafOcclusion:
    """The visible fraction of every leaf a view shows (``view``)."""

    def __init__(self, splats: SplatArrays) -> None:
        index = np.flatnonzero(splats.leaf & (splats.instances >= 0))
        order = index[np.argsort(splats.instances[index], kind="stable")]
        ids = splats.instances[order]
        self.ids, starts = np.unique(ids, return_index=True)
        self.bounds = np.r_[starts, len(order)]
        self.order = order  # the leaves' Gaussians, leaf by leaf
        # Their parameters once, leaf by leaf (a render takes slices).
        self.params = [
            np.ascontiguousarray(t.detach().numpy()[order])
            for t in (splats.means, splats.quats, splats.scales, splats.opacities)
        ]

    def view(self, camera: Camera, instance_map: np.ndarray, meta: dict[str, Any]) -> dict:
        """``{instance id: [alone, visible]}`` for the leaves ``instance_map`` (the view's
        instance ids per pixel, -1 none) shows; ``meta``: the view's render of all the
        Gaussians (its footprints give each leaf's tiles)."""
        present = _present(instance_map)
        shown = np.flatnonzero(np.isin(self.ids, present))  # indices into self.ids
        if not len(shown):
            return {}
        tiles = self._tiles(shown, camera, meta)  # bool [leaves, tiles_y, tiles_x]
        on_screen = tiles.any(axis=(1, 2))
        shown, tiles = shown[on_screen], tiles[on_screen]
        if not len(shown):
            return {}
        groups = _colour(tiles)
        calls, windows = [], []
        for members in groups:
            window = _window(tiles[members].any(axis=0), camera)
            windows.append(window)
            calls.append(self._call(shown[members], camera, window))
        return self._measure(calls, windows, groups, shown, tiles, instance_map)

    def _tiles(self, shown: np.ndarray, camera: Camera, meta: dict[str, Any]) -> np.ndarray:
        """The tiles each shown leaf's Gaussians can touch: their footprint boxes binned as
        the rasterizer bins them (float32, the same operations; ``pipeline.label_channels``
        paints the label maps' tiles so), with a 2-D difference array per leaf."""
        tiles_y, tiles_x = -(-camera.height // TILE), -(-camera.width // TILE)
        xy = meta["means2d"][0].detach().numpy()
        radii = meta["radii"][0].numpy()
        rows = np.concatenate([self.order[self.bounds[k] : self.bounds[k + 1]] for k in shown])
        leaf = np.repeat(np.arange(len(shown)), np.diff(self.bounds)[shown])
        seen = (radii[rows, 0] > 0) | (radii[rows, 1] > 0)
        rows, leaf = rows[seen], leaf[seen]
        inv = np.float32(1.0 / TILE)
        box = []
        for axis, count in ((0, tiles_x), (1, tiles_y)):
            centre, r = xy[rows, axis], radii[rows, axis].astype(np.float32)
            lo = np.maximum((centre - r) * inv, 0).astype(np.int64)
            hi = np.ceil(np.maximum((centre + r) * inv, 0)).astype(np.int64)
            box += [np.clip(lo, 0, count), np.clip(hi, 0, count)]
        x0, x1, y0, y1 = box
        base = leaf * (tiles_y + 1)
        corners = [
            ((base + y) * (tiles_x + 1) + x) for y, x in ((y0, x0), (y1, x1), (y0, x1), (y1, x0))
        ]
        size = len(shown) * (tiles_y + 1) * (tiles_x + 1)
        diff = np.bincount(np.concatenate(corners[:2]), minlength=size) - np.bincount(
            np.concatenate(corners[2:]), minlength=size
        )
        diff = diff.reshape(len(shown), tiles_y + 1, tiles_x + 1)
        return diff.cumsum(axis=1).cumsum(axis=2)[:, :tiles_y, :tiles_x] > 0

    def _call(self, leaves: np.ndarray, camera: Camera, window: tuple[int, ...]) -> dict:
        x0, y0, x1, y1 = window
        K = camera.K.copy()
        K[0, 2] -= x0
        K[1, 2] -= y0
        crop = replace(camera, K=K, width=x1 - x0, height=y1 - y0)
        viewmats, ks = stack([crop])
        spans = [slice(self.bounds[k], self.bounds[k + 1]) for k in leaves]
        means, quats, scales, opacities = (
            torch.from_numpy(np.concatenate([p[s] for s in spans])) for p in self.params
        )
        return {
            "means": means,
            "quats": quats,
            "scales": scales,
            "opacities": opacities,
            "colors": torch.ones((len(means), 1)),
            "viewmats": torch.from_numpy(viewmats),
            "Ks": torch.from_numpy(ks),
            "width": crop.width,
            "height": crop.height,
            "render_mode": "RGB",
            "tile_size": TILE,
        }

    def _measure(self, calls, windows, groups, shown, tiles, instance_map) -> dict:
        from plantdreamer.rasterizer import rasterization_many

        with torch.no_grad():  # one thread of its own: beside the run's renders
            results = rasterization_many(calls, threads=OWN_THREADS)
        out: dict[int, list[int]] = {}
        for window, members, result in zip(windows, groups, results, strict=True):
            if isinstance(result, Exception):
                raise result
            x0, y0, x1, y1 = window
            silhouette = result[1][0, ..., 0].numpy() >= ALPHA_THRESHOLD
            # alone: the silhouette's pixels in each member's own tiles (disjoint), by tile.
            h, w = silhouette.shape
            padded = np.zeros((-(-h // TILE) * TILE, -(-w // TILE) * TILE), dtype=np.int32)
            padded[:h, :w] = silhouette
            per_tile = padded.reshape(len(padded) // TILE, TILE, -1, TILE).sum(axis=(1, 3))
            own = tiles[members][:, y0 // TILE : -(-y1 // TILE), x0 // TILE : -(-x1 // TILE)]
            alone = (own * per_tile).sum(axis=(1, 2))
            # visible: the silhouette's pixels the instance map gives each member (a
            # leaf's pixels lie in its own tiles: no other member's).
            leaves = self.ids[shown[members]]
            shown_ids = instance_map[y0:y1, x0:x1][silhouette]
            slot = np.searchsorted(leaves, shown_ids)
            slot = np.minimum(slot, len(leaves) - 1)
            hits = slot[leaves[slot] == shown_ids]
            visible = np.bincount(hits, minlength=len(members))
            for j, leaf in enumerate(leaves):
                out[int(leaf)] = [int(alone[j]), int(visible[j])]
        return out


def _present(instance_map: np.ndarray) -> np.ndarray:
    """The instance ids of a map (-1: none), ascending, from 0 (the Gaussians a leaf's
    occlusion is measured for have ids from 0): counted per id where the ids are small
    (an L-System's are 0..~150), sorted otherwise (a scan's may be any int)."""
    top = int(instance_map.max(initial=-1))
    if top < 1 << 20 and int(instance_map.min(initial=-1)) >= -1:
        return np.flatnonzero(np.bincount((instance_map + 1).ravel(), minlength=top + 2)[1:])
    return np.unique(instance_map[instance_map >= 0])


def _colour(tiles: np.ndarray) -> list[np.ndarray]:
    """Groups of leaves whose tile sets do not meet (greedy, in leaf order)."""
    n = len(tiles)
    bits = np.packbits(tiles.reshape(n, -1), axis=1)
    meets = np.any(bits[:, None, :] & bits[None, :, :], axis=2)
    colour = np.zeros(n, dtype=np.int64)
    for i in range(n):
        taken = set(colour[:i][meets[i, :i]].tolist())
        colour[i] = next(c for c in range(len(taken) + 1) if c not in taken)
    return [np.flatnonzero(colour == c) for c in range(int(colour.max()) + 1)]


def _window(tiles: np.ndarray, camera: Camera) -> tuple[int, int, int, int]:
    """The pixels of the whole tiles around ``tiles`` (bool [tiles_y, tiles_x]), cut to
    the image: (x0, y0, x1, y1)."""
    ys, xs = np.flatnonzero(tiles.any(axis=1)), np.flatnonzero(tiles.any(axis=0))
    x0, y0 = int(xs[0]) * TILE, int(ys[0]) * TILE
    x1 = min(camera.width, (int(xs[-1]) + 1) * TILE)
    y1 = min(camera.height, (int(ys[-1]) + 1) * TILE)
    return x0, y0, x1, y1
