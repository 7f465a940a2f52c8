"""Per-pixel ground truth of a labelled model, rendered by the rasterizer: class, instance and
depth maps for one camera.

Rule (docs/labels.md): each label is a one-hot feature blended exactly like colour, so a
pixel's weight for class c is W_c = sum_i T_i alpha_i [label_i = c], the share of the pixel's
colour that Gaussians of class c produced. The pixel takes the class of largest weight (ties:
the smaller id) and is background where the accumulated alpha sum_c W_c is below
``ALPHA_THRESHOLD``. An opaque front leaf takes almost all the weight (the Gaussians behind it
get at most its transmittance), so occluding leaves win; at a leaf's soft edge the pixel
turns to whatever contributes most, as in the RGB image.

Instances use the same rule over one-hot instance features, plus one channel for Gaussians of
no instance (a stem in front of a leaf is "no instance", not the leaf). One channel per leaf
would cost hundreds of channels, so instances share channels: the view's RGB render (or a
depth-only pass) gives every Gaussian's footprint box, hence the tiles each instance can touch; two
instances whose tile sets are disjoint never both weigh on one pixel, so they can share a
channel (greedy colouring, in id order), and a pixel's channel names its instance through
the tile it lies in. The arg-max is the same as with one channel per instance (ties between
exactly equal weights go to the lower channel). A bean's 36 leaflets need 7-10
channels; at most ``CHANNELS_PER_PASS`` are blended per pass, keeping the running arg-max.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from plantdreamer.cameras import Camera, stack
from plantdreamer.pipeline.model import GaussianModel

ALPHA_THRESHOLD = 0.5  # below: background (also for depth)
CHANNELS_PER_PASS = 32  # instance channels blended per rasterizer pass
TILE = 16  # rasterizer tile size, the grain of the instance channel sharing


@dataclass
class GroundTruth:
    """Maps of one view, [H, W]. ``label``/``instance`` hold the ids of ``LabelSet``'s lists
    (-1: background, or no class / no instance); depth is camera-space z in scene units (0 on
    background); alpha is the accumulated opacity."""

    label: np.ndarray
    instance: np.ndarray
    depth: np.ndarray
    alpha: np.ndarray


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
        label, instance = labels[:, 0], labels[:, 1]
        classes = np.unique(label[label >= 0])
        instances = np.unique(instance[instance >= 0])
        class_channel = np.where(label >= 0, np.searchsorted(classes, label), -1)
        instance_channel = np.where(instance >= 0, np.searchsorted(instances, instance) + 1, 0)
        return cls(classes, instances, class_channel, instance_channel)


def render_ground_truth(
    model: GaussianModel,
    camera: Camera,
    label_set: LabelSet | None,
    footprints: dict | None = None,
) -> GroundTruth:
    """Class, instance and depth maps of ``model`` seen by ``camera`` (no labels: depth only).

    ``footprints``: the ``meta`` of a render of the same model and camera (the RGB view),
    whose projected footprints decide which instances share a channel; without it, a
    depth-only pass provides them.
    """
    shape = (camera.height, camera.width)
    depth = alpha = None
    if label_set is None or footprints is None:
        _, depth, alpha, footprints = _blend(
            model, camera, torch.zeros((len(model), 1)), with_depth=True
        )
    if label_set is None:
        assert depth is not None and alpha is not None
        empty = np.full(shape, -1, dtype=np.int64)
        return GroundTruth(empty, empty.copy(), _masked_depth(depth, alpha), alpha)

    n_cls = len(label_set.classes) + 1  # channel 0: unlabelled (occludes, names no class)
    channel = np.zeros(len(model), dtype=np.int64)
    owner = np.full((1, 1, 1), -1, dtype=np.int64)
    if len(label_set.instances):
        channel, owner = _share_channels(label_set, footprints, camera)
    n_inst = int(channel.max()) + 1 if len(label_set.instances) else 0
    first = min(n_inst, CHANNELS_PER_PASS)
    features = torch.cat(
        [_one_hot(label_set.class_channel + 1, 0, n_cls), _one_hot(channel, 0, first)], dim=1
    )
    weights, d, a, _ = _blend(model, camera, features, with_depth=depth is None)
    if depth is None:
        depth, alpha = d, a
    assert depth is not None and alpha is not None
    background = alpha < ALPHA_THRESHOLD
    label = np.where(background, -1, _arg_max(weights[..., :n_cls])[1] - 1)
    if not n_inst:
        return GroundTruth(label, np.full(shape, -1), _masked_depth(depth, alpha), alpha)
    best_w, best = _arg_max(weights[..., n_cls:])
    for start in range(first, n_inst, CHANNELS_PER_PASS):
        stop = min(start + CHANNELS_PER_PASS, n_inst)
        w, _, _, _ = _blend(model, camera, _one_hot(channel, start, stop), with_depth=False)
        chunk_w, chunk_c = _arg_max(w)
        better = chunk_w > best_w  # strict: ties keep the lower channel
        best_w = np.where(better, chunk_w, best_w)
        best = np.where(better, chunk_c + start, best)
    # The channel's instance at each pixel: its owner in the pixel's tile.
    ty = np.arange(camera.height) // TILE
    tx = np.arange(camera.width) // TILE
    instance = np.where(background, -1, owner[best, ty[:, None], tx[None, :]])
    return GroundTruth(label, instance, _masked_depth(depth, alpha), alpha)


def _share_channels(
    label_set: LabelSet, meta: dict, camera: Camera
) -> tuple[np.ndarray, np.ndarray]:
    """Each Gaussian's instance channel (0: no instance) and, per channel and tile, the index
    into ``label_set.instances`` of the instance owning it there (-1: none)."""
    tiles_y, tiles_x = -(-camera.height // TILE), -(-camera.width // TILE)
    n_inst = len(label_set.instances)
    which = label_set.instance_channel - 1  # instance index per Gaussian, -1: none
    xy = meta["means2d"][0].detach().numpy()
    radii = meta["radii"][0].numpy().astype(np.float32)  # whole numbers (ceiled), exact
    seen = (radii.max(axis=1) > 0) & (which >= 0)
    # The tiles of each footprint box, computed as the rasterizer's binning does (float32,
    # same operations; it bins a splat to no tile outside them); painted per instance with
    # a 2-D difference array.
    inv = np.float32(1.0 / TILE)
    lo = np.trunc(np.maximum((xy[seen] - radii[seen]) * inv, 0)).astype(np.int64)
    up = np.maximum((xy[seen] + radii[seen]) * inv, 0)
    hi = np.ceil(up).astype(np.int64)
    x0, x1 = np.clip(lo[:, 0], 0, tiles_x), np.clip(hi[:, 0], 0, tiles_x)
    y0, y1 = np.clip(lo[:, 1], 0, tiles_y), np.clip(hi[:, 1], 0, tiles_y)
    diff = np.zeros((n_inst, tiles_y + 1, tiles_x + 1), dtype=np.int64)
    inst = which[seen]
    for ys, xs, sign in ((y0, x0, 1), (y0, x1, -1), (y1, x0, -1), (y1, x1, 1)):
        np.add.at(diff, (inst, ys, xs), sign)
    touched = diff.cumsum(axis=1).cumsum(axis=2)[:, :tiles_y, :tiles_x] > 0
    # Greedy colouring in id order: the first channel none of whose instances share a tile.
    colour = np.zeros(n_inst, dtype=np.int64)
    used: list[np.ndarray] = []
    owner = [np.full((tiles_y, tiles_x), -1, dtype=np.int64)]  # channel 0: no instance
    for i in range(n_inst):
        k = next((k for k, u in enumerate(used) if not (u & touched[i]).any()), len(used))
        if k == len(used):
            used.append(np.zeros((tiles_y, tiles_x), dtype=bool))
            owner.append(np.full((tiles_y, tiles_x), -1, dtype=np.int64))
        used[k] |= touched[i]
        owner[k + 1][touched[i]] = i
        colour[i] = k + 1
    channel = np.where(which >= 0, colour[np.maximum(which, 0)], 0)
    return channel, np.stack(owner)


def _arg_max(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Max and arg-max over the last axis; equal maxima go to the first (torch.max's rule)."""
    values, indices = torch.from_numpy(w).max(dim=-1)
    return values.numpy(), indices.numpy()


def _one_hot(channel: np.ndarray, start: int, stop: int) -> torch.Tensor:
    """[N, stop - start] float32 with a 1 where ``channel`` falls in [start, stop)."""
    out = np.zeros((channel.shape[0], stop - start), dtype=np.float32)
    inside = (channel >= start) & (channel < stop)
    out[np.flatnonzero(inside), channel[inside] - start] = 1.0
    return torch.from_numpy(out)


def _blend(model: GaussianModel, camera: Camera, features: torch.Tensor, with_depth: bool):
    """Blended features [H, W, D], expected depth [H, W] (or None), alpha [H, W] and meta."""
    from plantdreamer.rasterizer import rasterization

    p = model.params
    viewmats, ks = stack([camera])
    with torch.no_grad():
        out, alpha, meta = rasterization(
            p["means"].detach(),
            p["quats"].detach(),
            torch.exp(p["log_scales"].detach()),
            torch.sigmoid(p["opacity_logits"].detach()),
            features,
            torch.from_numpy(viewmats),
            torch.from_numpy(ks),
            camera.width,
            camera.height,
            render_mode="RGB+D" if with_depth else "RGB",
            tile_size=TILE,
        )
    out_np, alpha_np = out[0].numpy(), alpha[0, ..., 0].numpy()
    if with_depth:  # expected depth, as "ED" makes it, on the depth plane alone
        depth = out_np[..., -1] / np.maximum(alpha_np, np.float32(1e-10))
        return out_np[..., :-1], depth, alpha_np, meta
    return out_np, None, alpha_np, meta


def _masked_depth(depth: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    return np.where(alpha < ALPHA_THRESHOLD, 0.0, depth).astype(np.float32)
