"""Image metrics for comparing renders with captured images.

Images are float arrays [H, W, 3] with values in [0, 1]; masks are [H, W] arrays whose
non-zero entries mark the plant (boolean masks are the usual case).

Masked PSNR follows the PlantDreamer authors' own tool: keep the pixels where the mask is
non-zero, take the MSE over the selected K x 3 values, PSNR with data range 1. Averaging over
images is done by the caller (``plantdreamer.eval.evaluate``).

Perfect render: PSNR is ``10 log10(1 / max(MSE, MSE_FLOOR))`` with ``MSE_FLOOR = 1e-10``, so a
pixel-identical image scores exactly ``PSNR_MAX_DB = 100`` dB instead of infinity. That keeps
per-dataset means finite and JSON reports valid. It differs from torchmetrics/scikit-image
(which return inf) only when the RMS error is below 1e-5, i.e. 400 times smaller than one
8-bit intensity step, so no real comparison is affected.
"""

from __future__ import annotations

import math

import numpy as np

from plantdreamer.errors import InputError

MSE_FLOOR = 1e-10
PSNR_MAX_DB = 100.0  # = -10 log10(MSE_FLOOR)

# SSIM settings of Wang et al. (2004), used by torchmetrics and scikit-image's gaussian mode.
SSIM_KERNEL_SIZE = 11
SSIM_SIGMA = 1.5

__all__ = [
    "MSE_FLOOR",
    "PSNR_MAX_DB",
    "mask_iou",
    "masked_psnr",
    "masked_ssim",
    "psnr",
    "psnr_from_mse",
]


def psnr_from_mse(mse: float) -> float:
    """PSNR in dB for data range 1; capped at ``PSNR_MAX_DB`` (see the module docstring)."""
    if not math.isfinite(mse) or mse < 0.0:
        raise InputError(f"MSE must be a finite non-negative number, got {mse}")
    return -10.0 * math.log10(max(mse, MSE_FLOOR))


def _image_pair(pred: np.ndarray, gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both images as float64 [H, W, 3], after checking shapes and values."""
    p = np.asarray(pred, dtype=np.float64)
    g = np.asarray(gt, dtype=np.float64)
    if p.ndim != 3 or p.shape[2] != 3:
        raise InputError(f"images must have shape [H, W, 3], got {list(p.shape)}")
    if p.shape != g.shape:
        raise InputError(
            f"render and ground truth differ in shape: {list(p.shape)} vs {list(g.shape)}"
        )
    if p.shape[0] == 0 or p.shape[1] == 0:
        raise InputError(f"images are empty: {list(p.shape)}")
    for name, img in (("render", p), ("ground truth", g)):
        if not np.isfinite(img).all():
            raise InputError(f"{name} image contains NaN or Inf")
    return p, g


def _mask(mask: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Boolean [H, W]: True where ``mask`` is non-zero (the authors' grayscale rule)."""
    m = np.asarray(mask)
    if m.ndim == 3 and m.shape[2] == 1:
        m = m[..., 0]
    if m.shape != tuple(shape[:2]):
        raise InputError(f"mask must have shape {list(shape[:2])}, got {list(m.shape)}")
    return m != 0


def psnr(pred: np.ndarray, gt: np.ndarray) -> float:
    """Full-image PSNR (dB, data range 1) over all H x W x 3 values."""
    p, g = _image_pair(pred, gt)
    return psnr_from_mse(float(np.mean((p - g) ** 2)))


def masked_psnr(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> float:
    """PSNR (dB, data range 1) over the pixels where ``mask`` is non-zero, all 3 channels.

    Raises InputError when the mask selects no pixel (the metric is undefined there).
    """
    p, g = _image_pair(pred, gt)
    keep = _mask(mask, p.shape)
    if not keep.any():
        raise InputError("mask selects no pixels: masked PSNR is undefined")
    return psnr_from_mse(float(np.mean((p[keep] - g[keep]) ** 2)))


def masked_ssim(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> float:
    """Mean SSIM over the pixels where ``mask`` is non-zero.

    The SSIM map is torchmetrics' (Gaussian window 11, sigma 1.5, data range 1, reflect
    padding, channels averaged). Outside the mask the render's pixels are replaced by the
    ground truth's before filtering, so nothing outside the mask can change the score;
    windows at the mask edge still see the (identical) surroundings. With an all-true mask
    this is the ordinary mean SSIM over the whole image map. Computed in float32. Images must
    be at least 6 pixels on each side (reflect padding by 5).
    """
    import torch
    from torchmetrics.functional.image import structural_similarity_index_measure

    p, g = _image_pair(pred, gt)
    keep = _mask(mask, p.shape)
    if not keep.any():
        raise InputError("mask selects no pixels: masked SSIM is undefined")
    pad = SSIM_KERNEL_SIZE // 2
    if min(p.shape[:2]) <= pad:
        raise InputError(f"SSIM needs images larger than {pad} pixels, got {list(p.shape[:2])}")
    p = np.where(keep[..., None], p, g)

    def tensor(img: np.ndarray) -> torch.Tensor:
        # float32: torch's float64 convolution on the CPU is about 10x slower.
        return torch.from_numpy(np.ascontiguousarray(img.transpose(2, 0, 1), np.float32))[None]

    pt, gt_t = tensor(p), tensor(g)
    _, ssim_map = structural_similarity_index_measure(
        pt,
        gt_t,
        gaussian_kernel=True,
        sigma=SSIM_SIGMA,
        kernel_size=SSIM_KERNEL_SIZE,
        data_range=1.0,
        return_full_image=True,
    )
    per_pixel = ssim_map[0].mean(dim=0).numpy()  # [H, W], channels averaged
    return float(per_pixel[keep].mean())


def mask_iou(pred_alpha: np.ndarray, gt_mask: np.ndarray, threshold: float = 0.5) -> float:
    """Intersection over union of ``pred_alpha > threshold`` and ``gt_mask != 0``.

    ``pred_alpha`` is the rendered opacity [H, W] (or [H, W, 1]). Two empty masks agree
    perfectly: IoU 1.0. A mask taken from a soft alpha matte (non-zero rule) includes the
    faint edge pixels, which a render's alpha > 0.5 does not: expect a slightly lower IoU there.
    """
    a = np.asarray(pred_alpha, dtype=np.float64)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    if a.ndim != 2:
        raise InputError(f"alpha must have shape [H, W], got {list(a.shape)}")
    if not np.isfinite(a).all():
        raise InputError("alpha contains NaN or Inf")
    gt = _mask(gt_mask, a.shape)
    pred = a > threshold
    union = int(np.count_nonzero(pred | gt))
    if union == 0:
        return 1.0
    return int(np.count_nonzero(pred & gt)) / union
