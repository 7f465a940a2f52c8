"""Metrics against hand-computed values and against torchmetrics."""

import math

import numpy as np
import pytest
import torch
from torchmetrics.functional.image import (
    peak_signal_noise_ratio,
    structural_similarity_index_measure,
)

from plantdreamer.errors import InputError
from plantdreamer.eval.metrics import (
    PSNR_MAX_DB,
    mask_iou,
    masked_psnr,
    masked_ssim,
    psnr,
    psnr_from_mse,
)


def _image(seed: int, h: int = 32, w: int = 40) -> np.ndarray:
    return np.random.default_rng(seed).random((h, w, 3)).astype(np.float32)


def test_known_mse_gives_known_psnr():
    gt = np.full((10, 10, 3), 0.5)
    pred = gt + 0.1  # every value off by 0.1: MSE = 0.01 -> 20 dB exactly
    assert psnr(pred, gt) == pytest.approx(20.0, abs=1e-9)
    pred = gt.copy()
    pred[0, 0, 0] += 0.3  # one value of 300 off by 0.3: MSE = 0.09 / 300
    assert psnr(pred, gt) == pytest.approx(-10 * math.log10(0.09 / 300), abs=1e-9)


def test_perfect_render_scores_the_documented_maximum():
    img = _image(0)
    assert psnr(img, img) == PSNR_MAX_DB == 100.0
    mask = np.zeros(img.shape[:2], bool)
    mask[3:9, 4:20] = True
    assert masked_psnr(img, img, mask) == PSNR_MAX_DB
    assert psnr_from_mse(0.0) == 100.0
    assert psnr_from_mse(1.0) == 0.0


def test_mask_excluding_a_corrupted_region_leaves_psnr_unchanged():
    gt = _image(1)
    pred = np.clip(gt + np.random.default_rng(2).normal(0, 0.05, gt.shape), 0, 1)
    mask = np.zeros(gt.shape[:2], bool)
    mask[5:25, 5:20] = True
    before = masked_psnr(pred, gt, mask)
    corrupted = pred.copy()
    corrupted[~mask] = 1.0 - gt[~mask]  # wreck everything outside the mask
    assert masked_psnr(corrupted, gt, mask) == before
    assert psnr(corrupted, gt) < psnr(pred, gt) - 5.0


def test_masked_psnr_is_the_authors_formula():
    # Their tool: keep pixels where the grayscale mask != 0, /255, PSNR(data_range=1) over
    # the selected K x 3 values. Uint8 images and a grayscale (0..255) mask.
    rng = np.random.default_rng(3)
    gt8 = rng.integers(0, 256, (20, 30, 3), dtype=np.uint8)
    pred8 = np.clip(gt8.astype(int) + rng.integers(-20, 21, gt8.shape), 0, 255).astype(np.uint8)
    gray = rng.choice([0, 1, 128, 255], size=(20, 30)).astype(np.uint8)
    sel = gray != 0
    mse = np.mean((pred8[sel] / 255.0 - gt8[sel] / 255.0) ** 2)
    expected = 10 * np.log10(1.0 / mse)
    assert masked_psnr(pred8 / 255.0, gt8 / 255.0, gray) == pytest.approx(expected, abs=1e-10)
    assert masked_psnr(pred8 / 255.0, gt8 / 255.0, sel) == pytest.approx(expected, abs=1e-10)


def test_agrees_with_torchmetrics_psnr():
    gt, pred = _image(4), _image(5)
    ours = psnr(pred, gt)
    theirs = peak_signal_noise_ratio(torch.from_numpy(pred), torch.from_numpy(gt), data_range=1.0)
    assert ours == pytest.approx(float(theirs), abs=1e-4)
    mask = np.random.default_rng(6).random(gt.shape[:2]) > 0.6
    theirs = peak_signal_noise_ratio(
        torch.from_numpy(pred[mask]), torch.from_numpy(gt[mask]), data_range=1.0
    )
    assert masked_psnr(pred, gt, mask) == pytest.approx(float(theirs), abs=1e-4)


def test_empty_mask_and_bad_shapes_raise():
    img = _image(7)
    with pytest.raises(InputError, match="no pixels"):
        masked_psnr(img, img, np.zeros(img.shape[:2], bool))
    with pytest.raises(InputError, match="no pixels"):
        masked_ssim(img, img, np.zeros(img.shape[:2], bool))
    with pytest.raises(InputError, match="shape"):
        psnr(img, img[:-1])
    with pytest.raises(InputError, match="shape"):
        psnr(img[..., :2], img[..., :2])
    with pytest.raises(InputError, match="mask"):
        masked_psnr(img, img, np.ones((3, 3), bool))
    bad = img.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        psnr(bad, img)


def test_ssim_identical_is_one_and_full_mask_matches_torchmetrics():
    gt = _image(8)
    full = np.ones(gt.shape[:2], bool)
    assert masked_ssim(gt, gt, full) == pytest.approx(1.0, abs=1e-6)
    pred = np.clip(gt + np.random.default_rng(9).normal(0, 0.1, gt.shape), 0, 1)
    ours = masked_ssim(pred, gt, full)
    # torchmetrics' own mean crops the reflect-padded border; compare with its full map mean.
    to_t = lambda a: torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1)))[None].float()  # noqa: E731
    _, ssim_map = structural_similarity_index_measure(
        to_t(pred), to_t(gt), data_range=1.0, return_full_image=True
    )
    assert ours == pytest.approx(float(ssim_map.mean()), abs=1e-6)
    assert 0.0 < ours < 1.0


def test_ssim_ignores_corruption_outside_the_mask():
    gt = _image(10, 48, 48)
    pred = np.clip(gt + np.random.default_rng(11).normal(0, 0.05, gt.shape), 0, 1)
    mask = np.zeros(gt.shape[:2], bool)
    mask[10:30, 12:36] = True
    before = masked_ssim(pred, gt, mask)
    corrupted = pred.copy()
    corrupted[~mask] = 0.0
    assert masked_ssim(corrupted, gt, mask) == before
    worse = pred.copy()
    worse[mask] = 1.0 - worse[mask]
    assert masked_ssim(worse, gt, mask) < before - 0.2


def test_ssim_rejects_tiny_images():
    img = _image(12, 4, 4)
    with pytest.raises(InputError, match="larger"):
        masked_ssim(img, img, np.ones((4, 4), bool))


def test_mask_iou_cases():
    gt = np.zeros((10, 10), bool)
    gt[:, :5] = True  # 50 pixels
    alpha = np.zeros((10, 10))
    alpha[:, :5] = 1.0
    assert mask_iou(alpha, gt) == 1.0
    assert mask_iou(alpha[..., None], gt) == 1.0
    alpha2 = np.zeros((10, 10))
    alpha2[:, 3:8] = 0.9  # 20 shared of 80 in the union
    assert mask_iou(alpha2, gt) == pytest.approx(20 / 80)
    assert mask_iou(np.zeros((10, 10)), gt) == 0.0
    # threshold is strict: alpha exactly 0.5 is background
    assert mask_iou(np.where(gt, 0.5, 0.0), gt) == 0.0
    assert mask_iou(np.where(gt, 0.5, 0.0), gt, threshold=0.4) == 1.0
    # both empty: perfect agreement
    assert mask_iou(np.zeros((4, 4)), np.zeros((4, 4), bool)) == 1.0
    with pytest.raises(InputError):
        mask_iou(np.zeros((4, 4)), np.zeros((5, 4), bool))
