"""How much of each visible leaf a view shows: the leaf's pixels in the view's instance map
against its pixels when its Gaussians are rendered alone from the same camera.

A leaf alone is its own Gaussians through the rasterizer, with the label renders'
settings, and its silhouette the pixels where their accumulated alpha reaches the label
maps' threshold (0.5). Only the window its Gaussians' footprints can touch is rendered:
the camera's principal point moved by the window's corner, whole tiles of the label
renders (16 px), so the window's tiles are the full view's. Every leaf of a view is one
scene of one ``rasterization_many`` call. A leaf's figures are ``alone`` (its silhouette's
pixels) and ``visible`` (those of them the view's instance map gives it); its visible
fraction is visible / alone.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from plantdreamer.cameras import Camera, stack

ALPHA_THRESHOLD = 0.5  # the label maps' foreground threshold (pipeline.ground_truth)
TILE = 16  # the label renders' tile size: windows start on its multiples


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
        self.splats = splats
        leaf = splats.leaf & (splats.instances >= 0)
        index = np.flatnonzero(leaf)
        ids = splats.instances[index]
        order = np.argsort(ids, kind="stable")
        self.ids, starts = np.unique(ids[order], return_index=True)
        bounds = np.r_[starts, len(order)]
        self.members = {
            int(i): index[order[bounds[k] : bounds[k + 1]]] for k, i in enumerate(self.ids)
        }

    def view(self, camera: Camera, instance_map: np.ndarray, meta: dict[str, Any]) -> dict:
        """``{instance id: [alone, visible]}`` for the leaves ``instance_map`` (the view's
        instance ids per pixel, -1 none) shows; ``meta``: the view's render of all the
        Gaussians (its footprints bound each leaf's window)."""
        present = np.unique(instance_map[instance_map >= 0])
        shown = [int(i) for i in present if int(i) in self.members]
        if not shown:
            return {}
        xy = meta["means2d"][0].detach().numpy()
        radii = meta["radii"][0].numpy()
        calls, windows = [], []
        for i in shown:
            window = _window(self.members[i], xy, radii, camera)
            if window is None:
                continue
            windows.append((i, window))
            calls.append(self._call(self.members[i], camera, window))
        return dict(self._measure(calls, windows, instance_map))

    def _call(self, members: np.ndarray, camera: Camera, window: tuple[int, ...]) -> dict:
        x0, y0, x1, y1 = window
        K = camera.K.copy()
        K[0, 2] -= x0
        K[1, 2] -= y0
        crop = replace(camera, K=K, width=x1 - x0, height=y1 - y0)
        viewmats, ks = stack([crop])
        take = torch.from_numpy(members)
        s = self.splats
        return {
            "means": s.means[take],
            "quats": s.quats[take],
            "scales": s.scales[take],
            "opacities": s.opacities[take],
            "colors": torch.ones((len(members), 1)),
            "viewmats": torch.from_numpy(viewmats),
            "Ks": torch.from_numpy(ks),
            "width": crop.width,
            "height": crop.height,
            "render_mode": "RGB",
            "tile_size": TILE,
        }

    @staticmethod
    def _measure(calls: list[dict], windows: list, instance_map: np.ndarray):
        from plantdreamer.rasterizer import rasterization_many

        with torch.no_grad():
            results = rasterization_many(calls)
        for (i, (x0, y0, x1, y1)), result in zip(windows, results, strict=True):
            if isinstance(result, Exception):
                raise result
            alone = result[1][0, ..., 0].numpy() >= ALPHA_THRESHOLD
            mine = instance_map[y0:y1, x0:x1] == i
            yield i, [int(alone.sum()), int((alone & mine).sum())]


def _window(
    members: np.ndarray, xy: np.ndarray, radii: np.ndarray, camera: Camera
) -> tuple[int, int, int, int] | None:
    """The pixels the footprints of ``members`` can touch, widened to whole tiles and cut
    to the image: (x0, y0, x1, y1), or None when none is on screen."""
    seen = members[(radii[members] > 0).any(axis=1)]
    if len(seen) == 0:
        return None
    lo = np.floor((xy[seen] - radii[seen]).min(axis=0)) - 1
    hi = np.ceil((xy[seen] + radii[seen]).max(axis=0)) + 1
    x0 = max(0, int(lo[0]) // TILE * TILE)
    y0 = max(0, int(lo[1]) // TILE * TILE)
    x1 = min(camera.width, int(hi[0]))
    y1 = min(camera.height, int(hi[1]))
    if x1 <= x0 or y1 <= y0:
        return None
    return x0, y0, x1, y1
