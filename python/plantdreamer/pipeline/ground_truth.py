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
from plantdreamer.gaussians import activate_opacities, activate_scales
from plantdreamer.labels import NO_CLASS, NO_INSTANCE
from plantdreamer.pipeline.model import GaussianModel

ALPHA_THRESHOLD = 0.5  # below: background (also for depth)
CHANNELS_PER_PASS = 32  # instance channels blended per rasterizer pass
TILE = 16  # tile_size of the label renders: the grain of the instance channel sharing


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
        """Only -1 means "none": every other id, negative ones included, is a class or an
        instance of its own."""
        label, instance = labels[:, 0], labels[:, 1]
        has_class, has_instance = label != NO_CLASS, instance != NO_INSTANCE
        classes = np.unique(label[has_class])
        instances = np.unique(instance[has_instance])
        class_channel = np.where(has_class, np.searchsorted(classes, label), -1)
        instance_channel = np.where(has_instance, np.searchsorted(instances, instance) + 1, 0)
        return cls(classes, instances, class_channel, instance_channel)


@dataclass(frozen=True)
class Splats:
    """A model's activated parameters (scales, opacities), computed once for all its views."""

    means: torch.Tensor
    quats: torch.Tensor
    scales: torch.Tensor
    opacities: torch.Tensor

    @classmethod
    def of(cls, model: GaussianModel) -> Splats:
        p = model.params
        with torch.no_grad():
            return cls(
                p["means"].detach(),
                p["quats"].detach(),
                torch.from_numpy(activate_scales(p["log_scales"].detach().numpy())),
                torch.from_numpy(activate_opacities(p["opacity_logits"].detach().numpy())),
            )

    def __len__(self) -> int:
        return self.means.shape[0]


class GroundTruthRenderer:
    """Renders the ground truth of one model for any number of views; what does not depend
    on the view (activated parameters, class channels) is prepared once."""

    def __init__(self, model: GaussianModel, label_set: LabelSet | None) -> None:
        self.splats = Splats.of(model)
        self.label_set = label_set
        if label_set is not None:
            # Channel 0 is "unlabelled" (it occludes and names no class) only where some
            # Gaussian has label -1; otherwise channel k is class k.
            self.unlabelled = int((label_set.class_channel < 0).any())
            self.class_column = label_set.class_channel + self.unlabelled
            self.n_cls = len(label_set.classes) + self.unlabelled

    def __call__(self, camera: Camera, footprints: dict | None = None) -> GroundTruth:
        """Class, instance and depth maps seen by ``camera`` (no labels: depth only).

        ``footprints``: the ``meta`` of a render of the same model and camera (the RGB
        view), whose projected footprints decide which instances share a channel; without
        it, a depth-only pass provides them.
        """
        shape, n = (camera.height, camera.width), len(self.splats)
        ls = self.label_set
        depth = alpha = None
        if ls is None or footprints is None:
            _, depth, alpha, footprints = _blend(
                self.splats, camera, torch.zeros((n, 1)), with_depth=True
            )
        if ls is None:
            assert depth is not None and alpha is not None
            empty = np.full(shape, -1, dtype=np.int64)
            return GroundTruth(empty, empty.copy(), _masked_depth(depth, alpha), alpha)

        channel = np.zeros(n, dtype=np.int64)
        owner = np.full((1, 1, 1), -1, dtype=np.int64)
        if len(ls.instances):
            channel, owner = _share_channels(ls, footprints, camera)
        n_inst = int(channel.max()) + 1 if len(ls.instances) else 0
        first = min(n_inst, CHANNELS_PER_PASS)
        # Classes and the first instance channels in one [N, n_cls + first] feature block.
        # A row is one of n_cls x (first + 1) patterns (its class; its instance channel, or
        # none in this pass): one gather from a table of them.
        d = self.n_cls + first
        table = np.zeros((self.n_cls, first + 1, d), dtype=np.float32)
        table[np.arange(self.n_cls), :, np.arange(self.n_cls)] = 1.0
        table[:, np.arange(first), self.n_cls + np.arange(first)] = 1.0
        pattern = self.class_column * (first + 1) + np.minimum(channel, first)
        features = table.reshape(-1, d)[pattern]
        weights, d, a, _ = _blend(
            self.splats, camera, torch.from_numpy(features), with_depth=depth is None
        )
        if depth is None:
            depth, alpha = d, a
        assert depth is not None and alpha is not None
        # Arg-max over the foreground pixels only (usually a small part of the frame).
        fg = np.flatnonzero(alpha.reshape(-1) >= ALPHA_THRESHOLD)
        w = weights.reshape(-1, weights.shape[-1])[fg]
        label = np.full(shape[0] * shape[1], -1, dtype=np.int64)
        label[fg] = np.argmax(w[:, : self.n_cls], axis=1) - self.unlabelled
        label = label.reshape(shape)
        if not n_inst:
            return GroundTruth(label, np.full(shape, -1), _masked_depth(depth, alpha), alpha)
        best = np.argmax(w[:, self.n_cls :], axis=1)
        best_w = w[np.arange(len(fg)), self.n_cls + best]
        for start in range(first, n_inst, CHANNELS_PER_PASS):
            stop = min(start + CHANNELS_PER_PASS, n_inst)
            more, _, _, _ = _blend(
                self.splats, camera, _one_hot(channel, start, stop), with_depth=False
            )
            chunk = more.reshape(-1, stop - start)[fg]
            chunk_c = np.argmax(chunk, axis=1)
            chunk_w = chunk[np.arange(len(fg)), chunk_c]
            better = chunk_w > best_w  # strict: ties keep the lower channel
            best_w = np.where(better, chunk_w, best_w)
            best = np.where(better, chunk_c + start, best)
        # The channel's instance at each pixel: its owner in the pixel's tile.
        instance = np.full(shape[0] * shape[1], -1, dtype=np.int64)
        instance[fg] = owner[best, fg // camera.width // TILE, fg % camera.width // TILE]
        return GroundTruth(label, instance.reshape(shape), _masked_depth(depth, alpha), alpha)


def render_ground_truth(
    model: GaussianModel,
    camera: Camera,
    label_set: LabelSet | None,
    footprints: dict | None = None,
) -> GroundTruth:
    """One view's ground truth (``GroundTruthRenderer``; make one to render many views)."""
    return GroundTruthRenderer(model, label_set)(camera, footprints)


def _share_channels(
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


def _one_hot(channel: np.ndarray, start: int, stop: int) -> torch.Tensor:
    """[N, stop - start] float32 with a 1 where ``channel`` falls in [start, stop)."""
    out = np.zeros((channel.shape[0], stop - start), dtype=np.float32)
    inside = (channel >= start) & (channel < stop)
    out[np.flatnonzero(inside), channel[inside] - start] = 1.0
    return torch.from_numpy(out)


def _blend(splats: Splats, camera: Camera, features: torch.Tensor, with_depth: bool):
    """Blended features [H, W, D], expected depth [H, W] (or None), alpha [H, W] and meta."""
    from plantdreamer.rasterizer import rasterization

    viewmats, ks = stack([camera])
    with torch.no_grad():
        out, alpha, meta = rasterization(
            splats.means,
            splats.quats,
            splats.scales,
            splats.opacities,
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
