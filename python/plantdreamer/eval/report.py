"""Evaluation reports: markdown + JSON, the image strip, and the colour-ablation table."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from plantdreamer import atomic
from plantdreamer.errors import InputError
from plantdreamer.eval.evaluate import EvalResult, View
from plantdreamer.eval.metrics import PSNR_MAX_DB

__all__ = [
    "ERROR_MAP_MAX",
    "write_ablation_table",
    "write_image_strip",
    "write_json",
    "write_markdown",
]

# Fixed colour scale of the error heat map (per-pixel RMS over R, G, B), so strips of
# different models can be compared by eye.
ERROR_MAP_MAX = 0.5

_LABELS = {
    "masked_psnr": "masked PSNR (dB)",
    "psnr": "PSNR (dB)",
    "masked_ssim": "masked SSIM",
    "mask_iou": "mask IoU",
}


def _fmt(value: float | None, digits: int = 2) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def _digits(name: str) -> int:
    return 2 if "psnr" in name else 4


def write_json(result: EvalResult, path: str | Path, **extra: object) -> Path:
    """The result as strict JSON (no NaN/Inf): means, counts and per-frame scores."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    data = {**extra, **result.to_dict()}
    atomic.write_json(out, data, allow_nan=False)
    return out


def write_markdown(
    result: EvalResult,
    path: str | Path,
    *,
    title: str = "Evaluation",
    strip: str | Path | None = None,
    details: dict[str, str] | None = None,
) -> Path:
    """A human-readable report: the mean table, how the metrics are defined, per-frame table."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    mean, counts = result.mean, result.counts()
    lines = [f"# {title}", ""]
    for key, value in (details or {}).items():
        lines.append(f"- {key}: {value}")
    bg = ", ".join(f"{c:g}" for c in result.background)
    lines += [f"- frames: {len(result.frames)}", f"- background: ({bg})", ""]
    lines += ["| metric | mean | frames |", "|---|---|---|"]
    for name in _LABELS:
        lines.append(f"| {_LABELS[name]} | {_fmt(mean[name], _digits(name))} | {counts[name]} |")
    lines += [
        "",
        "Masked PSNR is computed as the PlantDreamer authors do: the pixels where the ground-truth "
        "mask is non-zero, values in [0, 1], MSE over those pixels' R, G, B values, PSNR with "
        "data range 1, then the mean over frames. Renders are clipped and rounded to 8 bits, "
        "like a saved PNG. An identical image scores "
        f"{PSNR_MAX_DB:g} dB (MSE floored at 1e-10). Masked SSIM: mean of the SSIM map "
        "(Gaussian window 11, sigma 1.5) over the mask. Mask IoU: rendered alpha > 0.5 vs the "
        "mask. n/a: the dataset has no masks.",
        "",
    ]
    if strip is not None:
        lines += [f"![ground truth | render | error]({Path(strip).name})", ""]
    lines += ["## Per frame", "", "| frame | " + " | ".join(_LABELS.values()) + " |"]
    lines.append("|---" * (len(_LABELS) + 1) + "|")
    for f in result.frames:
        cells = [_fmt(getattr(f, name), _digits(name)) for name in _LABELS]
        lines.append(f"| {f.name} | " + " | ".join(cells) + " |")
    atomic.write_text(out, "\n".join(lines) + "\n")
    return out


def _error_map(render: np.ndarray, gt: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean((render.astype(np.float64) - gt) ** 2, axis=2))


def write_image_strip(views: Sequence[View], path: str | Path) -> Path:
    """One row per view: ground truth | render | error heat map (mask outline in cyan)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if not views:
        raise InputError("no views to draw")
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    h, w = views[0].ground_truth.shape[:2]
    panel = 3.2
    fig = Figure(
        figsize=(3 * panel + 0.8, len(views) * (panel * h / w + 0.3)), dpi=100, layout="compressed"
    )
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(views), 3, squeeze=False)
    image = None
    for row, view in zip(axes, views, strict=True):
        m = view.metrics
        score = f"masked PSNR {_fmt(m.masked_psnr)} dB" if m.masked_psnr is not None else ""
        row[0].imshow(np.clip(view.ground_truth, 0.0, 1.0))
        row[0].set_title(f"{view.metrics.name}: ground truth", fontsize=8)
        row[1].imshow(np.clip(view.render, 0.0, 1.0))
        row[1].set_title(f"render  PSNR {m.psnr:.2f} dB", fontsize=8)
        image = row[2].imshow(
            _error_map(view.render, view.ground_truth), cmap="inferno", vmin=0, vmax=ERROR_MAP_MAX
        )
        if view.mask is not None and view.mask.any() and not view.mask.all():
            row[2].contour(view.mask.astype(float), levels=[0.5], colors="cyan", linewidths=0.6)
        row[2].set_title(f"RMS error  {score}", fontsize=8)
        for ax in row:
            ax.set_axis_off()
    assert image is not None
    fig.colorbar(image, ax=axes[:, 2].tolist(), fraction=0.05, shrink=0.8, label="RMS error")
    atomic.atomic_write(out, fig.savefig)
    return out


def write_ablation_table(
    results: dict[str, float], out_dir: str | Path, *, metric: str = "PSNR Masked (dB)"
) -> tuple[Path, Path]:
    """The paper's colour-initialisation table (best value in bold) and a bar plot.

    ``results`` maps a setting (``original``, ``noise``, ``black``, ``white``, ...) to its
    masked PSNR; the order of the dict is the order of the rows. Writes ``ablation.md`` and
    ``ablation.png`` in ``out_dir`` and returns their paths.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if not results:
        raise InputError("no ablation results to write")
    for name, value in results.items():
        if not isinstance(value, (int, float)) or not math.isfinite(value):
            raise InputError(f"ablation result for {name!r} must be a finite number, got {value}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    best = max(results.values())
    lines = [f"| Colour | {metric} |", "|---|---|"]
    for name, value in results.items():
        cell = f"**{value:.2f}**" if value == best else f"{value:.2f}"
        lines.append(f"| {name.capitalize()} | {cell} |")
    md = out / "ablation.md"
    atomic.write_text(md, "\n".join(lines) + "\n")

    fig = Figure(figsize=(1.2 * len(results) + 2.0, 3.2), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    labels = [n.capitalize() for n in results]
    bars = ax.bar(labels, list(results.values()), color="#4c9a2a")
    ax.bar_label(bars, fmt="%.2f", fontsize=8)
    ax.set_ylabel(metric)
    ax.set_title("Colour initialisation")
    ax.margins(y=0.15)
    fig.tight_layout()
    png = out / "ablation.png"
    atomic.atomic_write(png, fig.savefig)
    return md, png
