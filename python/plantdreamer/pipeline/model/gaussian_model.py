"""The trainable 3DGS model: parameters, their Adam optimiser, and rendering.

Densification and culling change the number of Gaussians; ``remove`` and ``append`` keep the
optimiser state (exp_avg, exp_avg_sq) aligned with the parameters, as the 3DGS reference does,
and the labels (not trained) aligned with both.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from plantdreamer.cameras import Camera, stack
from plantdreamer.gaussians import Gaussians, activate_opacities, activate_scales
from plantdreamer.pipeline.settings.train_config import LearningRates

PARAM_NAMES = ("means", "quats", "log_scales", "opacity_logits", "sh_dc", "sh_rest")
# torch's Adam for the Gaussians runs as its fused implementation: one pass over each
# parameter's memory instead of the "foreach" form's several. It is elementwise, so its bits
# do not depend on the thread count, and it agrees with a float64 Adam to float32's
# rounding (tests/test_model_adam.py); measured about 3x faster on a plant's step
# (BENCHMARKS.md, "Before and after: the depth map at the SDS size and the fused Adam").


class _Activations(torch.autograd.Function):
    """(log scales, opacity logits) -> (scales, opacities), one node, in numpy on one thread
    (``gaussians.activate_*``). The gradients are torch's own formulas in its order:
    exp's ``v * y`` and sigmoid's ``(v * (1 - y)) * y``."""

    @staticmethod
    def forward(  # type: ignore[override]
        ctx: Any, log_scales: torch.Tensor, logits: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        scales = activate_scales(log_scales.detach().cpu().numpy())
        opacities = activate_opacities(logits.detach().cpu().numpy())
        ctx.set_materialize_grads(False)
        ctx.activated = scales, opacities
        return torch.from_numpy(scales), torch.from_numpy(opacities)

    @staticmethod
    def backward(ctx: Any, v_scales: Any, v_opacities: Any) -> tuple[Any, Any]:
        scales, opacities = ctx.activated
        g_scales = g_logits = None
        if v_scales is not None and ctx.needs_input_grad[0]:
            g_scales = torch.from_numpy(_array(v_scales) * scales)
        if v_opacities is not None and ctx.needs_input_grad[1]:
            g = _array(v_opacities) * (np.float32(1.0) - opacities)
            g_logits = torch.from_numpy(np.multiply(g, opacities, out=g))
        return g_scales, g_logits


def _array(t: torch.Tensor) -> np.ndarray:
    return t.detach().to(torch.float32).contiguous().numpy()


class GaussianModel:
    def __init__(self, gaussians: Gaussians, lr: LearningRates | None = None) -> None:
        sh = torch.from_numpy(np.ascontiguousarray(gaussians.sh, dtype=np.float32))
        tensors = {
            "means": torch.from_numpy(gaussians.means.astype(np.float32)),
            "quats": torch.from_numpy(gaussians.quats.astype(np.float32)),
            "log_scales": torch.from_numpy(gaussians.log_scales.astype(np.float32)),
            "opacity_logits": torch.from_numpy(gaussians.opacity_logits.astype(np.float32)),
            "sh_dc": sh[:, :1].clone(),
            "sh_rest": sh[:, 1:].clone(),
        }
        self.params = {k: torch.nn.Parameter(v.contiguous()) for k, v in tensors.items()}
        # [N, 2] int32 (label, instance) or None; follows the Gaussians through every change.
        self.labels = (
            None if gaussians.labels is None else torch.from_numpy(gaussians.labels.copy())
        )
        self.sh_degree = gaussians.sh_degree
        self.optimizer: torch.optim.Adam | None = None
        if lr is not None:
            rates = {
                "means": lr.means,
                "quats": lr.quats,
                "log_scales": lr.scales,
                "opacity_logits": lr.opacity,
                "sh_dc": lr.sh_dc,
                "sh_rest": lr.sh_rest,
            }
            self.optimizer = torch.optim.Adam(
                [{"params": [self.params[k]], "lr": rates[k], "name": k} for k in PARAM_NAMES],
                eps=lr.eps,
                fused=True,
            )

    def __len__(self) -> int:
        return int(self.params["means"].shape[0])

    def to_gaussians(self) -> Gaussians:
        p = {k: v.detach().cpu().numpy() for k, v in self.params.items()}
        return Gaussians(
            p["means"].copy(),
            p["quats"].copy(),
            p["log_scales"].copy(),
            p["opacity_logits"].copy(),
            np.concatenate([p["sh_dc"], p["sh_rest"]], axis=1),
            None if self.labels is None else self.labels.numpy().copy(),
        )

    def render(
        self,
        cameras: Sequence[Camera],
        background: float,
        render_mode: str = "RGB",
    ) -> tuple[torch.Tensor, torch.Tensor, dict]:
        """Renders [C, H, W, ch] images (and alphas, meta) through the native rasterizer."""
        from plantdreamer.rasterizer import rasterization

        return rasterization(**self.render_call(cameras, background, render_mode))

    def render_call(
        self, cameras: Sequence[Camera], background: float, render_mode: str = "RGB"
    ) -> dict[str, Any]:
        """``rasterization``'s keyword arguments for a render of ``cameras``."""
        return self.scene_args(render_mode) | camera_args(cameras, background, render_mode)

    def scene_args(self, render_mode: str = "RGB") -> dict[str, Any]:
        """The Gaussians' part of ``render_call``: activated and differentiable."""
        p = self.params
        # Copies only where needed: no concatenation at degree 0 (no sh_rest), and none for
        # depth renders, which never read the colours (a view of the right shape will do).
        k = 1 + p["sh_rest"].shape[1]
        if "RGB" not in render_mode:
            colors = p["sh_dc"].expand(-1, k, -1)
        elif k == 1:
            colors = p["sh_dc"]
        else:
            colors = torch.cat([p["sh_dc"], p["sh_rest"]], dim=1)
        scales, opacities = _Activations.apply(p["log_scales"], p["opacity_logits"])
        return {
            "means": p["means"],
            "quats": p["quats"],
            "scales": scales,
            "opacities": opacities,
            "colors": colors,
            "sh_degree": self.sh_degree,
            "render_mode": render_mode,
        }

    # -- changing the set of Gaussians -------------------------------------------------

    def remove(self, mask: torch.Tensor) -> None:
        """Drops the Gaussians where ``mask`` is True (and their optimiser state)."""
        keep = ~mask
        self._replace(lambda name, t: t[keep], lambda name, s: s[keep])
        if self.labels is not None:
            self.labels = self.labels[keep]

    def append(self, new: dict[str, torch.Tensor]) -> None:
        """Adds Gaussians (one tensor per parameter name, and "labels" when the model has
        labels); their optimiser state starts at 0."""
        self._replace(
            lambda name, t: torch.cat([t, new[name].to(t.dtype)]),
            lambda name, s: torch.cat([s, torch.zeros_like(new[name], dtype=s.dtype)]),
        )
        if self.labels is not None:
            self.labels = torch.cat([self.labels, new["labels"]])

    def _replace(self, edit_param, edit_state) -> None:
        for name in PARAM_NAMES:
            old = self.params[name]
            fresh = torch.nn.Parameter(edit_param(name, old.detach()).contiguous())
            if self.optimizer is not None:
                state = self.optimizer.state.pop(old, None)
                group = next(g for g in self.optimizer.param_groups if g["name"] == name)
                group["params"][0] = fresh
                if state:
                    state["exp_avg"] = edit_state(name, state["exp_avg"])
                    state["exp_avg_sq"] = edit_state(name, state["exp_avg_sq"])
                    self.optimizer.state[fresh] = state
            self.params[name] = fresh

    # -- checkpoints ---------------------------------------------------------------------

    def state_dict(self) -> dict:
        return {
            "params": {k: v.detach().clone() for k, v in self.params.items()},
            "sh_degree": self.sh_degree,
            "optimizer": None if self.optimizer is None else self.optimizer.state_dict(),
            "labels": None if self.labels is None else self.labels.clone(),
        }

    def load_state_dict(self, state: dict) -> None:
        for name in PARAM_NAMES:
            self.params[name] = torch.nn.Parameter(state["params"][name].clone())
        self.sh_degree = int(state["sh_degree"])
        labels = state.get("labels")
        self.labels = None if labels is None else labels.clone()
        if self.optimizer is not None:
            for group in self.optimizer.param_groups:
                group["params"][0] = self.params[group["name"]]
            self.optimizer.state.clear()
            self.optimizer.load_state_dict(state["optimizer"])
            # The implementation is this build's, not the checkpoint's (one written before
            # the fused Adam names "foreach"; a run resumed from it goes on fused).
            for group in self.optimizer.param_groups:
                group["foreach"], group["fused"] = False, True


def camera_args(
    cameras: Sequence[Camera], background: float, render_mode: str = "RGB"
) -> dict[str, Any]:
    """The cameras' part of ``render_call``."""
    viewmats, ks = stack(cameras)
    bg = None
    if "RGB" in render_mode:
        bg = torch.full((len(cameras), 3), float(background))
    return {
        "viewmats": torch.from_numpy(viewmats),
        "Ks": torch.from_numpy(ks),
        "width": cameras[0].width,
        "height": cameras[0].height,
        "backgrounds": bg,
    }
