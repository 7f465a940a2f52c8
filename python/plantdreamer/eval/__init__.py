"""Evaluation against posed ground-truth images: masked PSNR (as the PlantDreamer authors
compute it), PSNR, masked SSIM, mask IoU, dataset loaders and reports.

Heavy imports (torch, matplotlib) happen inside the functions that need them.
"""

from __future__ import annotations

from plantdreamer.eval.datasets import (
    load_colmap_text,
    load_dataset,
    load_transforms_json,
    scan_colmap_text,
    scan_dataset,
    scan_transforms_json,
)
from plantdreamer.eval.evaluate import DEFAULT_BACKGROUND, EvalResult, FrameMetrics, evaluate
from plantdreamer.eval.frames import Frame, FrameSource
from plantdreamer.eval.metrics import PSNR_MAX_DB, mask_iou, masked_psnr, masked_ssim, psnr

__all__ = [
    "DEFAULT_BACKGROUND",
    "PSNR_MAX_DB",
    "EvalResult",
    "Frame",
    "FrameMetrics",
    "FrameSource",
    "evaluate",
    "load_colmap_text",
    "load_dataset",
    "load_transforms_json",
    "mask_iou",
    "masked_psnr",
    "masked_ssim",
    "psnr",
    "scan_colmap_text",
    "scan_dataset",
    "scan_transforms_json",
]
