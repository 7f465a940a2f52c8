"""Per-pixel ground truth of a labelled model, rendered by the rasterizer: class, instance and
depth maps for one camera.

Rule (docs/labels.md): each label is a one-hot feature blended exactly like colour, so a
pixel's weight for class c is W_c = sum_i T_i alpha_i [label_i = c], the share of the pixel's
colour that Gaussians of class c produced. The pixel takes the class of largest weight (ties:
the smaller id) and is background where the accumulated alpha sum_c W_c is below
``ALPHA_THRESHOLD``. An opaque front leaf takes almost all the weight (the Gaussians behind it
get at most its transmittance), so occluding leaves win; at a leaf's soft edge the pixel
turns to whatever contributes most, as in the RGB image.

Instances are chosen within the pixel's class: among the units of that class (its
instances, and its Gaussians of no instance; ``label_channels.py``), the one of largest
weight, by the same rule over one-hot unit features; a pixel of a class without instances
(a stem in front of a leaf) has no instance. Units whose footprints never meet share a
channel, and at most ``CHANNELS_PER_PASS`` channels are blended per pass, keeping the
running arg-max. Last, a view's specks (stray pieces of an object under
``label_pieces.MIN_PIECE`` pixels) take the label around them; depth is kept where the
class map is foreground.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from plantdreamer.cameras import Camera, stack
from plantdreamer.gaussians import activate_opacities, activate_scales
from plantdreamer.pipeline.model.gaussian_model import GaussianModel
from plantdreamer.pipeline.truth.label_channels import TILE, LabelSet, one_hot, share_channels
from plantdreamer.pipeline.truth.label_pieces import BACKGROUND, MIN_PIECE, remove_specks

ALPHA_THRESHOLD = 0.5  # below: background (also for depth)
CHANNELS_PER_PASS = 32  # instance channels blended per rasterizer pass
NO_UNIT_CLASS = -2  # the class of "no unit": equal to no pixel's class (-1 is label -1)


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
    on the view (activated parameters, class channels) is prepared once. ``min_piece``:
    the speck size of ``label_pieces`` (1: the bare per-pixel arg-max)."""

    def __init__(
        self, model: GaussianModel, label_set: LabelSet | None, min_piece: int = MIN_PIECE
    ) -> None:
        self.splats = Splats.of(model)
        self.label_set = label_set
        self.min_piece = min_piece
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
        if n == 0:  # nothing to see: background everywhere
            empty = np.full(shape, -1, dtype=np.int64)
            zeros = np.zeros(shape, dtype=np.float32)
            return GroundTruth(empty, empty.copy(), zeros, zeros.copy())
        depth = alpha = None
        if ls is None or footprints is None:
            _, depth, alpha, footprints = _blend(
                self.splats, camera, torch.zeros((n, 1)), with_depth=True
            )
        if ls is None:
            assert depth is not None and alpha is not None
            empty = np.full(shape, -1, dtype=np.int64)
            return GroundTruth(empty, empty.copy(), _masked_depth(depth, alpha), alpha)
        fg, cls, unit, d, a = self._arg_max(camera, footprints, with_depth=depth is None)
        if depth is None:
            depth, alpha = d, a
        assert depth is not None and alpha is not None
        # One key per object (a unit; or a class, for pixels of no unit), then no specks
        # (a speck only ever moves to another object or to the background).
        n_keys = self.n_cls + 1
        key = np.full(shape[0] * shape[1], BACKGROUND, dtype=np.int64)
        key[fg] = np.where(unit >= 0, n_keys + unit, cls + 1)
        key = remove_specks(key.reshape(shape), self.min_piece).reshape(-1)[fg]
        u = np.where(key >= n_keys, key - n_keys, -1)
        label = np.full(shape[0] * shape[1], -1, dtype=np.int64)
        instance = label.copy()
        label[fg] = np.where(u >= 0, np.r_[ls.unit_class, -1][u], np.maximum(key - 1, -1))
        instance[fg] = np.r_[ls.unit_instance, -1][u]
        kept = np.zeros(shape[0] * shape[1], dtype=bool)
        kept[fg[key != BACKGROUND]] = True
        depth = np.where(kept.reshape(shape), depth, np.float32(0.0)).astype(np.float32)
        return GroundTruth(label.reshape(shape), instance.reshape(shape), depth, alpha)

    def _arg_max(self, camera: Camera, footprints: dict, with_depth: bool):
        """The foreground pixels (flat indices), each one's class index and unit (-1: none),
        and the depth and alpha maps (None without ``with_depth``)."""
        ls, n = self.label_set, len(self.splats)
        assert ls is not None
        channel = np.full(n, -1, dtype=np.int64)
        owner = np.full((0, 1, 1), -1, dtype=np.int64)
        if len(ls.unit_class):
            channel, owner = share_channels(ls, footprints, camera)
        n_ch = len(owner)
        first = min(n_ch, CHANNELS_PER_PASS)
        # Classes and the first instance channels in one [N, n_cls + first] feature block.
        # A row is one of n_cls x (first + 1) patterns (its class; its instance channel, or
        # none in this pass): one gather from a table of them.
        d = self.n_cls + first
        table = np.zeros((self.n_cls, first + 1, d), dtype=np.float32)
        table[np.arange(self.n_cls), :, np.arange(self.n_cls)] = 1.0
        table[:, np.arange(first), self.n_cls + np.arange(first)] = 1.0
        in_pass = np.where((channel >= 0) & (channel < first), channel, first)
        features = table.reshape(-1, d)[self.class_column * (first + 1) + in_pass]
        weights, depth, alpha, _ = _blend(
            self.splats, camera, torch.from_numpy(features), with_depth=with_depth
        )
        # Arg-max over the foreground pixels only (usually a small part of the frame).
        fg = np.flatnonzero(alpha.reshape(-1) >= ALPHA_THRESHOLD)
        w = weights.reshape(-1, weights.shape[-1])[fg]
        cls = np.argmax(w[:, : self.n_cls], axis=1) - self.unlabelled
        unit = np.full(len(fg), -1, dtype=np.int64)
        if not n_ch:
            return fg, cls, unit, depth, alpha
        # The instance: the unit of largest weight among those of the pixel's class (the
        # channel's unit in the pixel's tile; index -1 of unit_class: no unit there).
        tile = fg // camera.width // TILE * owner.shape[-1] + fg % camera.width // TILE
        units = owner.reshape(n_ch, -1)[:, tile].T  # [fg, channel]
        unit_class = np.r_[ls.unit_class, NO_UNIT_CLASS]
        best = np.zeros(len(fg), dtype=np.int64)
        best_w = np.zeros(len(fg), dtype=np.float32)
        for start in range(0, n_ch, CHANNELS_PER_PASS):
            stop = min(start + CHANNELS_PER_PASS, n_ch)
            if start == 0:
                chunk = w[:, self.n_cls :]
            else:
                more, _, _, _ = _blend(
                    self.splats, camera, one_hot(channel, start, stop), with_depth=False
                )
                chunk = more.reshape(-1, stop - start)[fg]
            mine = unit_class[units[:, start:stop]] == cls[:, None]
            chunk = np.where(mine, chunk, np.float32(-1.0))
            chunk_c = np.argmax(chunk, axis=1)
            chunk_w = chunk[np.arange(len(fg)), chunk_c]
            better = chunk_w > best_w  # strict: ties keep the lower channel
            best_w = np.where(better, chunk_w, best_w)
            best = np.where(better, chunk_c + start, best)
        unit = np.where(best_w > 0, units[np.arange(len(fg)), best], -1)
        return fg, cls, unit, depth, alpha


def render_ground_truth(
    model: GaussianModel,
    camera: Camera,
    label_set: LabelSet | None,
    footprints: dict | None = None,
    min_piece: int = MIN_PIECE,
) -> GroundTruth:
    """One view's ground truth (``GroundTruthRenderer``; make one to render many views)."""
    return GroundTruthRenderer(model, label_set, min_piece)(camera, footprints)


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
