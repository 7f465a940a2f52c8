"""Render a 3DGS model at every ground-truth camera and score it against the images."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from plantdreamer.cameras import Camera, stack
from plantdreamer.errors import InputError, PlantDreamerError
from plantdreamer.eval import metrics
from plantdreamer.eval.frames import Frame, FrameSource
from plantdreamer.gaussians import Gaussians

__all__ = [
    "DEFAULT_BACKGROUND",
    "METRIC_NAMES",
    "EvalResult",
    "FrameMetrics",
    "RenderFn",
    "View",
    "evaluate",
    "render_view",
]

# The constant grey the generation pipeline renders on (docs/method.md: background 0.75).
DEFAULT_BACKGROUND: tuple[float, float, float] = (0.75, 0.75, 0.75)
METRIC_NAMES = ("masked_psnr", "psnr", "masked_ssim", "mask_iou")

# (gaussians, camera, background) -> (rgb float32 [H, W, 3], alpha float32 [H, W])
RenderFn = Callable[[Gaussians, Camera, tuple[float, float, float]], tuple[np.ndarray, np.ndarray]]


@dataclass
class FrameMetrics:
    """Scores of one view. Masked scores are None when the frame has no (or an empty) mask."""

    name: str
    psnr: float
    masked_psnr: float | None
    masked_ssim: float | None
    mask_iou: float | None


@dataclass
class View:
    """A kept render with its ground truth, for the image strip."""

    metrics: FrameMetrics
    ground_truth: np.ndarray
    render: np.ndarray
    mask: np.ndarray | None


@dataclass
class EvalResult:
    frames: list[FrameMetrics]
    background: tuple[float, float, float]
    views: list[View] = field(default_factory=list)

    @property
    def mean(self) -> dict[str, float | None]:
        """Mean of each metric over the frames where it is defined (None if none is)."""
        out: dict[str, float | None] = {}
        for name in METRIC_NAMES:
            values = [getattr(f, name) for f in self.frames if getattr(f, name) is not None]
            out[name] = float(np.mean(values)) if values else None
        return out

    def counts(self) -> dict[str, int]:
        """How many frames each mean is taken over."""
        return {
            name: sum(getattr(f, name) is not None for f in self.frames) for name in METRIC_NAMES
        }

    def to_dict(self) -> dict[str, object]:
        return {
            "background": list(self.background),
            "mean": self.mean,
            "counts": self.counts(),
            "frames": [asdict(f) for f in self.frames],
        }


def _rasterization() -> Callable[..., Any]:
    from plantdreamer.rasterizer import rasterization  # imports torch: only when rendering

    return rasterization


def render_view(
    gaussians: Gaussians, camera: Camera, background: tuple[float, float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """RGB [H, W, 3] and alpha [H, W] of ``gaussians`` seen by ``camera`` (project rasterizer)."""
    import torch

    rasterization = _rasterization()
    viewmats, ks = stack([camera])

    def tensor(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))

    with torch.no_grad():
        colors, alphas, _ = rasterization(
            means=tensor(gaussians.means),
            quats=tensor(gaussians.quats),
            scales=tensor(gaussians.scales()),
            opacities=tensor(gaussians.opacities()),
            colors=tensor(gaussians.sh),
            viewmats=tensor(viewmats),
            Ks=tensor(ks),
            width=camera.width,
            height=camera.height,
            sh_degree=gaussians.sh_degree,
            backgrounds=tensor(np.asarray([background])),
            render_mode="RGB",
        )
    rgb = colors[0].detach().cpu().numpy()
    alpha = alphas[0, ..., 0].detach().cpu().numpy()
    return rgb, alpha


def _as_saved_png(rgb: np.ndarray) -> np.ndarray:
    """Clip to [0, 1] and round to 8 bits: the authors scored renders saved as PNG files."""
    return (np.round(np.clip(rgb, 0.0, 1.0) * 255.0) / 255.0).astype(np.float32)


def _score(name: str, render: np.ndarray, alpha: np.ndarray, gt: np.ndarray, mask) -> FrameMetrics:
    full = metrics.psnr(render, gt)
    if mask is None:
        return FrameMetrics(name, full, None, None, None)
    iou = metrics.mask_iou(alpha, mask)
    if not mask.any():  # nothing of the plant in view: masked scores are undefined
        return FrameMetrics(name, full, None, None, iou)
    return FrameMetrics(
        name,
        full,
        metrics.masked_psnr(render, gt, mask),
        metrics.masked_ssim(render, gt, mask),
        iou,
    )


def _kept_indices(n: int, keep: int) -> set[int]:
    if keep <= 0 or n == 0:
        return set()
    return {int(i) for i in np.round(np.linspace(0, n - 1, min(keep, n)))}


def evaluate(
    gaussians: Gaussians,
    frames: Sequence[Frame | FrameSource],
    background: Sequence[float] = DEFAULT_BACKGROUND,
    *,
    keep_views: int = 4,
    render: RenderFn | None = None,
    on_frame: Callable[[int, FrameMetrics], None] | None = None,
) -> EvalResult:
    """Render ``gaussians`` at every frame's camera and score each view.

    The render (over ``background``) is clipped and rounded to 8 bits and compared with the
    frame's image (RGBA images composited over the same background): full PSNR, and where the
    frame has a mask, masked PSNR, masked SSIM and the IoU of rendered alpha > 0.5 vs the
    mask. ``keep_views`` evenly spaced views are kept for the image strip. ``render``
    replaces the project rasterizer (tests, other renderers). ``FrameSource``s are read one
    at a time, so memory stays flat on large captures.
    """
    bg = tuple(float(c) for c in background)
    if len(bg) != 3 or not all(np.isfinite(bg)):
        raise InputError(f"background must be three finite numbers, got {list(background)}")
    if not frames:
        raise InputError("the dataset has no frames")
    render_fn = render or render_view
    keep = _kept_indices(len(frames), keep_views)
    result = EvalResult([], (bg[0], bg[1], bg[2]))
    for i, item in enumerate(frames):
        frame = item.load() if isinstance(item, FrameSource) else item
        rgb, alpha = render_fn(gaussians, frame.camera, result.background)
        shape = (frame.camera.height, frame.camera.width)
        if rgb.shape != (*shape, 3) or alpha.shape != shape:
            raise PlantDreamerError(
                f"renderer returned {list(rgb.shape)} / {list(alpha.shape)} for a "
                f"{shape[1]}x{shape[0]} camera"
            )
        if not (np.isfinite(rgb).all() and np.isfinite(alpha).all()):
            raise PlantDreamerError(f"render of frame {frame.name} contains NaN or Inf")
        rgb = _as_saved_png(rgb)
        gt = frame.ground_truth(result.background)
        scores = _score(frame.name, rgb, alpha, gt, frame.mask)
        result.frames.append(scores)
        if i in keep:
            result.views.append(View(scores, gt, rgb, frame.mask))
        if on_frame is not None:
            on_frame(i, scores)
    return result
