"""How much of each visible leaf a view shows: the leaf's pixels in the view's instance map
against its pixels when its Gaussians are rendered alone from the same camera.

A leaf alone is its own Gaussians through the rasterizer, with the view render's
projection, and its silhouette the pixels where their accumulated alpha reaches the label
maps' threshold (0.5). One native call per view measures every leaf the view shows
(``_core.group_coverage``) on the view's own render pass (``meta["state"]``): its
projection and depth order serve every leaf, each leaf gets tile lists of its own, and a
pixel stops as soon as it is in the leaf's silhouette; no image is made. Its counts are
those of thresholding each leaf's own render (tested against ``rasterization`` of the leaf
alone). A leaf's figures are ``alone`` (its silhouette's pixels) and ``visible`` (those of
them that the view's instance map gives it); its visible fraction is visible / alone.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from plantdreamer import _core

ALPHA_THRESHOLD = 0.5  # the label maps' foreground threshold (pipeline.ground_truth)
# The leaves' tile lists: any size gives the same counts (the images do not depend on it);
# 32 measured faster than 16 and 24 on a bean's views (interleaved, min and median).
TILE = 32


class LeafOcclusion:
    """The visible fraction of every leaf a view shows (``view``), for renders of
    Gaussians with these instance ids (-1: none) and leaf flags."""

    def __init__(self, instances: np.ndarray, leaf: np.ndarray) -> None:
        index = np.flatnonzero(leaf & (instances >= 0))
        self.ids = np.unique(instances[index]).astype(np.int32)
        # Each Gaussian's leaf: its place in ids, -1 for none.
        self.leaf_of = np.full(len(instances), -1, dtype=np.int64)
        self.leaf_of[index] = np.searchsorted(self.ids, instances[index])

    def view(self, instance_map: np.ndarray, state: Any) -> dict[int, list[int]]:
        """``{instance id: [alone, visible]}`` for the leaves ``instance_map`` (the view's
        instance ids per pixel, -1 none) shows; ``state``: the view's render pass
        (``meta["state"]``, one camera) of these Gaussians."""
        present = _present(instance_map)
        shown = np.flatnonzero(np.isin(self.ids, present))  # indices into self.ids
        if not len(shown):
            return {}
        # Each Gaussian's group in the call: its leaf's place in shown, -1 for none.
        place = np.full(len(self.ids) + 1, -1, dtype=np.int32)  # [-1]: a Gaussian of none
        place[shown] = np.arange(len(shown), dtype=np.int32)
        alone, visible = _core.group_coverage(
            state, place[self.leaf_of], np.ascontiguousarray(instance_map, dtype=np.int32),
            self.ids[shown], alpha_threshold=ALPHA_THRESHOLD, tile_size=TILE,
        )  # fmt: skip
        leaves = self.ids[shown].tolist()
        return {int(i): [int(a), int(v)] for i, a, v in zip(leaves, alone, visible, strict=True)}


def _present(instance_map: np.ndarray) -> np.ndarray:
    """The instance ids of a map (-1: none), ascending, from 0 (the Gaussians a leaf's
    occlusion is measured for have ids from 0): counted per id where the ids are small
    (an L-System's are 0..~150), sorted otherwise (a scan's may be any int)."""
    top = int(instance_map.max(initial=-1))
    if top < 1 << 20 and int(instance_map.min(initial=-1)) >= -1:
        return np.flatnonzero(np.bincount((instance_map + 1).ravel(), minlength=top + 2)[1:])
    return np.unique(instance_map[instance_map >= 0])
