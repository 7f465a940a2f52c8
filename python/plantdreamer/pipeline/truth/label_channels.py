"""Which one-hot feature channel each Gaussian's class and instance blend into.

Classes take one channel each (``ground_truth.py`` blends them). Instances are chosen within
a pixel's class, so they blend per *unit*: a (class, instance) pair of a class that carries
instances, with one "no instance" unit per such class for its Gaussians of no instance (a
scan's unsegmented leaf points); Gaussians of a class that carries no instances (an
L-System plant's stems, pot and soil) blend into no instance channel at all. One channel per
unit would cost hundreds of channels, so units share channels: the view's RGB render (or a
depth-only pass) gives every Gaussian's footprint box, hence the tiles each unit can touch;
two units whose tile sets are disjoint never both weigh on one pixel, so they can share a
channel (greedy colouring, in unit order), and a pixel's channel names its unit through the
tile it lies in. The arg-max is the same as with one channel per unit (ties between exactly
equal weights go to the lower channel). A bean's 36 leaflets need 7-10 channels; at most
``ground_truth.CHANNELS_PER_PASS`` are blended per pass.
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
    """The distinct classes and instances of a model (ascending), each Gaussian's class
    index, and the units instances are chosen among (see the module's docstring)."""

    classes: np.ndarray
    instances: np.ndarray
    class_channel: np.ndarray  # [N] index into classes, -1 for label -1
    instance_channel: np.ndarray  # [N] 0 for instance -1, else 1 + index into instances
    unit: np.ndarray  # [N] index into the units, -1 for a class that carries no instances
    unit_class: np.ndarray  # [U] each unit's class index (-1: label -1)
    unit_instance: np.ndarray  # [U] each unit's index into instances (-1: no instance)

    @classmethod
    def of(cls, labels: np.ndarray) -> LabelSet:
        """Only -1 means "none": every other id, negative ones included, is a class or an
        instance of its own."""
        label, instance = labels[:, 0], labels[:, 1]
        has_class, has_instance = label != NO_CLASS, instance != NO_INSTANCE
        classes = np.unique(label[has_class])
        instances = np.unique(instance[has_instance])
        class_channel = np.where(has_class, np.searchsorted(classes, label), -1)
        instance_index = np.where(has_instance, np.searchsorted(instances, instance), -1)
        # Units: the (class, instance) pairs of the classes that carry an instance somewhere,
        # in (class, instance) order, "no instance" (-1) first within its class.
        carrying = np.isin(class_channel, class_channel[has_instance])
        pairs = np.stack([class_channel[carrying], instance_index[carrying]], axis=1)
        unit = np.full(len(labels), -1, dtype=np.int64)
        units = np.zeros((0, 2), dtype=np.int64)
        if len(pairs):
            units, inverse = np.unique(pairs, axis=0, return_inverse=True)
            unit[carrying] = inverse.reshape(-1)
        return cls(
            classes,
            instances,
            class_channel,
            instance_index + 1,
            unit,
            units[:, 0].astype(np.int64),
            units[:, 1].astype(np.int64),
        )


def share_channels(
    label_set: LabelSet, meta: dict, camera: Camera
) -> tuple[np.ndarray, np.ndarray]:
    """Each Gaussian's instance channel (-1: none, its class carries no instances) and, per
    channel and tile, the unit owning it there (-1: none)."""
    tiles_y, tiles_x = -(-camera.height // TILE), -(-camera.width // TILE)
    n_units = len(label_set.unit_class)
    which = label_set.unit  # unit per Gaussian, -1: none
    xy = meta["means2d"][0].detach().numpy()
    radii = meta["radii"][0].numpy()  # int32, whole numbers (ceiled): exact in float32
    seen = np.flatnonzero(((radii[:, 0] > 0) | (radii[:, 1] > 0)) & (which >= 0))
    # The tiles of each footprint box, computed as the rasterizer's binning does (float32,
    # same operations; it bins a splat to no tile outside them); painted per unit with
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
    size = n_units * (tiles_y + 1) * (tiles_x + 1)
    diff = np.bincount(np.concatenate(corners[:2]), minlength=size) - np.bincount(
        np.concatenate(corners[2:]), minlength=size
    )
    diff = diff.reshape(n_units, tiles_y + 1, tiles_x + 1)
    touched = diff.cumsum(axis=1).cumsum(axis=2)[:, :tiles_y, :tiles_x] > 0
    # Greedy colouring in unit order: the first channel none of whose units share a tile.
    # Which units meet: an AND of the tile sets' bits (a float product would go through
    # BLAS, whose thread pool cost ~30 ms under load); a unit owns, in its channel, the
    # tiles it touches.
    bits = np.packbits(touched.reshape(n_units, -1), axis=1)
    meets: np.ndarray = np.any(bits[:, None, :] & bits[None, :, :], axis=2)
    colour = np.zeros(n_units, dtype=np.int64)
    for i in range(n_units):
        taken = set(colour[:i][meets[i, :i]].tolist())
        colour[i] = next(k for k in range(len(taken) + 1) if k not in taken)
    owner = np.full((int(colour.max(initial=-1)) + 1, tiles_y, tiles_x), -1, dtype=np.int64)
    who, ty, tx = np.nonzero(touched)
    owner[colour[who], ty, tx] = who  # one owner per channel and tile: disjoint tile sets
    channel = np.where(which >= 0, colour[np.maximum(which, 0)], -1)
    return channel, owner


def one_hot(channel: np.ndarray, start: int, stop: int) -> torch.Tensor:
    """[N, stop - start] float32 with a 1 where ``channel`` falls in [start, stop)."""
    out = np.zeros((channel.shape[0], stop - start), dtype=np.float32)
    inside = (channel >= start) & (channel < stop)
    out[np.flatnonzero(inside), channel[inside] - start] = 1.0
    return torch.from_numpy(out)
