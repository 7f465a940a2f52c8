"""Which one-hot feature channel each Gaussian's class and instance blend into.

Classes take one channel each (``ground_truth.py`` blends them); instances take one-hot
instance features plus one channel for Gaussians of no instance. One channel per leaf
would cost hundreds of channels, so instances share channels: the view's RGB render (or a
depth-only pass) gives every Gaussian's footprint box, hence the tiles each instance can touch; two
instances whose tile sets are disjoint never both weigh on one pixel, so they can share a
channel (greedy colouring, in id order), and a pixel's channel names its instance through
the tile it lies in. The arg-max is the same as with one channel per instance (ties between
exactly equal weights go to the lower channel). A bean's 36 leaflets need 7-10
channels; at most ``ground_truth.CHANNELS_PER_PASS`` are blended per pass.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from plantdreamer.cameras import Camera
from plantdreamer.labels import NO_CLASS, NO_INSTANCE

TILE = 16  # tile_size of the label renders: the grain of the instance channel sharing


@dataclass(frozen=True)
class LabelSet:
    """The distinct classes and instances of a model (ascending), and each Gaussian's channel
    in the one-hot features (channel 0 is "none" for instances)."""

    classes: np.ndarray
    instances: np.ndarray
    class_channel: np.ndarray  # [N] index into classes, -1 for label -1
    instance_channel: np.ndarray  # [N] 0 for instance -1, else 1 + index into instances

    @classmethod
    def of(cls, labels: np.ndarray) -> LabelSet:
        """Only -1 means "none": every other id, negative ones included, is a class or an
        instance of its own."""
        label, instance = labels[:, 0], labels[:, 1]
        has_class, has_instance = label != NO_CLASS, instance != NO_INSTANCE
        classes = np.unique(label[has_class])
        instances = np.unique(instance[has_instance])
        class_channel = np.where(has_class, np.searchsorted(classes, label), -1)
        instance_channel = np.where(has_instance, np.searchsorted(instances, instance) + 1, 0)
        return cls(classes, instances, class_channel, instance_channel)


def share_channels(
    label_set: LabelSet, meta: dict, camera: Camera
) -> tuple[np.ndarray, np.ndarray]:
    """Each Gaussian's instance channel (0: no instance) and, per channel and tile, the index
    into ``label_set.instances`` of the instance owning it there (-1: none)."""
    tiles_y, tiles_x = -(-camera.height // TILE), -(-camera.width // TILE)
    n_inst = len(label_set.instances)
    which = label_set.instance_channel - 1  # instance index per Gaussian, -1: none
    xy = meta["means2d"][0].detach().numpy()
    radii = meta["radii"][0].numpy()  # int32, whole numbers (ceiled): exact in float32
    seen = np.flatnonzero(((radii[:, 0] > 0) | (radii[:, 1] > 0)) & (which >= 0))
    # The tiles of each footprint box, computed as the rasterizer's binning does (float32,
    # same operations; it bins a splat to no tile outside them); painted per instance with
    # a 2-D difference array. Per axis on the seen splats only: the [N, 2] form cost 8 ms.
    inv = np.float32(1.0 / TILE)
    box = []
    for axis, tiles in ((0, tiles_x), (1, tiles_y)):
        centre, r = xy[seen, axis], radii[seen, axis].astype(np.float32)
        lo = np.maximum((centre - r) * inv, 0).astype(np.int64)  # >= 0: truncation is floor
        hi = np.ceil(np.maximum((centre + r) * inv, 0)).astype(np.int64)
        box += [np.clip(lo, 0, tiles), np.clip(hi, 0, tiles)]
    x0, x1, y0, y1 = box
    inst = which[seen] * (tiles_y + 1)
    corners = [
        ((inst + y) * (tiles_x + 1) + x) for y, x in ((y0, x0), (y1, x1), (y0, x1), (y1, x0))
    ]
    size = n_inst * (tiles_y + 1) * (tiles_x + 1)
    diff = np.bincount(np.concatenate(corners[:2]), minlength=size) - np.bincount(
        np.concatenate(corners[2:]), minlength=size
    )
    diff = diff.reshape(n_inst, tiles_y + 1, tiles_x + 1)
    touched = diff.cumsum(axis=1).cumsum(axis=2)[:, :tiles_y, :tiles_x] > 0
    # Greedy colouring in id order: the first channel none of whose instances share a tile
    # (channels from 1; 0 is "no instance"). Which instances meet: an AND of the tile sets'
    # bits (a float product would go through BLAS, whose thread pool cost ~30 ms under
    # load); an instance owns, in its channel, the tiles it touches.
    bits = np.packbits(touched.reshape(n_inst, -1), axis=1)
    meets: np.ndarray = np.any(bits[:, None, :] & bits[None, :, :], axis=2)
    colour = np.zeros(n_inst, dtype=np.int64)
    for i in range(n_inst):
        taken = set(colour[:i][meets[i, :i]].tolist())
        colour[i] = next(k for k in range(1, len(taken) + 2) if k not in taken)
    owner = np.full((int(colour.max(initial=0)) + 1, tiles_y, tiles_x), -1, dtype=np.int64)
    who, ty, tx = np.nonzero(touched)
    owner[colour[who], ty, tx] = who  # one owner per channel and tile: disjoint tile sets
    channel = np.where(which >= 0, colour[np.maximum(which, 0)], 0)
    return channel, owner


def one_hot(channel: np.ndarray, start: int, stop: int) -> torch.Tensor:
    """[N, stop - start] float32 with a 1 where ``channel`` falls in [start, stop)."""
    out = np.zeros((channel.shape[0], stop - start), dtype=np.float32)
    inside = (channel >= start) & (channel < stop)
    out[np.flatnonzero(inside), channel[inside] - start] = 1.0
    return torch.from_numpy(out)
