"""The operations of adaptive density control (gsplat's ``strategy/ops.py``): the
statistics it gathers, removing Gaussians with their statistics, and the 3DGS rules: clone
small and split large Gaussians with large 2D-mean gradients, prune transparent ones. Deterministic for a given seed and step. Clones and split
samples inherit their parent's label and instance."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import torch

from plantdreamer.pipeline.model.gaussian_model import GaussianModel


@dataclass
class DensifyStats:
    """Running mean of the view-space (NDC) 2D-mean gradient norm per Gaussian, and the
    largest screen radius (pixels) each reached, since the last densify round."""

    grad_sum: torch.Tensor
    count: torch.Tensor
    max_radius: torch.Tensor | None = None  # None (checkpoints without it): zeros

    def __post_init__(self) -> None:
        if self.max_radius is None:
            self.max_radius = torch.zeros(len(self.count), dtype=torch.float32)

    @classmethod
    def zeros(cls, n: int) -> DensifyStats:
        return cls(torch.zeros(n, dtype=torch.float64), torch.zeros(n, dtype=torch.int64))

    def subset(self, keep: torch.Tensor) -> DensifyStats:
        assert self.max_radius is not None
        return DensifyStats(self.grad_sum[keep], self.count[keep], self.max_radius[keep])

    def update(self, means2d_grad: torch.Tensor, radii: torch.Tensor, width: int, height: int):
        """Adds one step's gradients. ``means2d_grad`` [C, N, 2] in pixels, ``radii`` [C, N...]."""
        c = means2d_grad.shape[0]
        # Pixel -> NDC units, as in 3DGS and gsplat (the 2e-4 threshold is in NDC units).
        g = means2d_grad.detach().to(torch.float64).clone()
        g[..., 0] *= width / 2.0 * c
        g[..., 1] *= height / 2.0 * c
        radius = radii.reshape(c, radii.shape[1], -1).amax(dim=-1)
        visible = radius > 0
        norms = torch.linalg.vector_norm(g, dim=-1) * visible
        self.grad_sum += norms.sum(dim=0)
        self.count += visible.sum(dim=0)
        assert self.max_radius is not None
        self.max_radius = torch.maximum(self.max_radius, radius.amax(dim=0).float().cpu())

    def mean(self) -> torch.Tensor:
        return self.grad_sum / self.count.clamp(min=1)


def remove(model: GaussianModel, stats: DensifyStats, mask: torch.Tensor) -> DensifyStats:
    """The Gaussians under ``mask`` leave the parameters, Adam's state and the per-Gaussian
    statistics together (gsplat's ``strategy/ops.py:remove``); returns the statistics of
    the Gaussians kept."""
    model.remove(mask)
    return stats.subset(~mask)


def densify_and_prune(
    model: GaussianModel,
    stats: DensifyStats,
    grad_threshold: float,
    split_scale: float,
    prune_opacity: float,
    max_gaussians: int,
    generator: torch.Generator,
    cap_rule: str = "strongest",
    split_std: float = 1.0,
    prune_screen_px: float | None = None,
) -> dict[str, int]:
    """One densify-and-prune round; returns how many were cloned, split, pruned and capped.

    ``cap_rule`` keeps the count at ``max_gaussians``: "strongest" densifies only the
    strongest gradients that fit; "random" (the released code) densifies every selected
    Gaussian, then prunes a random subset back down to the cap. ``split_std`` is the std of
    the split samples as a fraction of the scale (the released code: 0.5).
    ``prune_screen_px``: first remove the Gaussians whose screen radius exceeded this since
    the last round (the released code's 1000 px prune, before it densifies).
    """
    if cap_rule not in ("strongest", "random"):
        raise ValueError(f"unknown cap rule {cap_rule!r}")
    too_big = 0
    if prune_screen_px is not None:
        assert stats.max_radius is not None
        big = stats.max_radius > prune_screen_px
        if bool(big.any()):
            model.remove(big)
            stats = stats.subset(~big)
            too_big = int(big.sum())
    p = model.params
    n = len(model)
    grads = stats.mean()
    with torch.no_grad():
        max_scale = torch.exp(p["log_scales"]).amax(dim=1)
        selected = grads >= grad_threshold
        budget = max(0, max_gaussians - n)
        if cap_rule == "strongest" and int(selected.sum()) > budget:
            # Keep the strongest gradients; stable order makes ties deterministic.
            order = torch.argsort(grads.masked_fill(~selected, -1.0), descending=True, stable=True)
            selected = torch.zeros_like(selected)
            selected[order[:budget]] = True
        clone = selected & (max_scale <= split_scale)
        split = selected & (max_scale > split_scale)

        new = {k: v.detach()[clone] for k, v in p.items()}
        split_new = _split(p, split, generator, split_std)
        for k in new:
            new[k] = torch.cat([new[k], split_new[k]])
        if model.labels is not None:  # the clones, then both samples of each split
            parents = model.labels[split]
            new["labels"] = torch.cat([model.labels[clone], parents, parents])
        model.append(new)
        # Remove the split originals (they are replaced by two smaller samples).
        split_full = torch.cat([split, torch.zeros(len(model) - n, dtype=torch.bool)])
        model.remove(split_full)

        opacity = torch.sigmoid(model.params["opacity_logits"])
        pruned = opacity < prune_opacity
        model.remove(pruned)
        capped = 0
        if cap_rule == "random" and len(model) > max_gaussians:
            over = random_cap_mask(len(model), max_gaussians, generator)
            model.remove(over)
            capped = int(over.sum())
    return {
        "cloned": int(clone.sum()),
        "split": int(split.sum()),
        "pruned": int(pruned.sum()),
        "capped": capped,
        "too_big": too_big,
    }


def random_cap_mask(n: int, cap: int, generator: torch.Generator) -> torch.Tensor:
    """True for the ``n - cap`` Gaussians a random prune removes to keep ``cap`` of ``n``
    (a random permutation from the run's generator; the released code's rule)."""
    if n <= cap:
        return torch.zeros(n, dtype=torch.bool)
    return torch.randperm(n, generator=generator) >= cap


def _split(
    p: Mapping[str, torch.Tensor], mask: torch.Tensor, generator: torch.Generator, std: float = 1.0
):
    """Two samples from each selected Gaussian with std ``std`` x scale, scales divided by 1.6
    (3DGS rule)."""
    if not bool(mask.any()):
        return {k: v.detach()[mask] for k, v in p.items()}
    means = p["means"].detach()[mask]
    scales = torch.exp(p["log_scales"].detach()[mask])
    quats = torch.nn.functional.normalize(p["quats"].detach()[mask], dim=-1)
    rot = _quat_to_rotmat(quats)
    samples = []
    for _ in range(2):
        noise = torch.randn(means.shape, generator=generator, dtype=means.dtype) * scales * std
        samples.append(means + torch.einsum("nij,nj->ni", rot, noise))
    out = {k: torch.cat([v.detach()[mask]] * 2) for k, v in p.items()}
    out["means"] = torch.cat(samples)
    out["log_scales"] = out["log_scales"] - torch.log(torch.tensor(1.6))
    return out


def _quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(-1, 3, 3)  # fmt: skip
