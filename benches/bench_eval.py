"""Cost of the evaluation metrics per view at the paper's evaluation size (768 x 768).

Writes benches/results/eval.md and eval.json. Run: python benches/bench_eval.py
The render itself is not timed here (that is the rasterizer's benchmark); this measures what
`plantdreamer eval` adds per view, and the float32 SSIM against torchmetrics in float64.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch
from torchmetrics.functional.image import structural_similarity_index_measure

from plantdreamer.eval.metrics import mask_iou, masked_psnr, masked_ssim, psnr

SIZE = 768
REPS = 3
RESULTS = Path(__file__).resolve().parent / "results"


def best_of(fn, reps: int = REPS) -> float:
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    rng = np.random.default_rng(0)
    gt = rng.random((SIZE, SIZE, 3)).astype(np.float32)
    pred = np.clip(gt + rng.normal(0, 0.1, gt.shape), 0, 1).astype(np.float32)
    yy, xx = np.mgrid[:SIZE, :SIZE]
    mask = (yy - SIZE / 2) ** 2 + (xx - SIZE / 2) ** 2 < (SIZE / 3) ** 2
    alpha = mask.astype(np.float32) * 0.9

    rows = {
        "psnr": best_of(lambda: psnr(pred, gt)),
        "masked_psnr": best_of(lambda: masked_psnr(pred, gt, mask)),
        "masked_ssim (float32 torchmetrics map)": best_of(lambda: masked_ssim(pred, gt, mask)),
        "mask_iou": best_of(lambda: mask_iou(alpha, mask)),
    }

    def ssim64() -> float:
        def t(a: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1), np.float64))[None]

        sel = np.where(mask[..., None], pred, gt)
        _, m = structural_similarity_index_measure(
            t(sel), t(gt), data_range=1.0, return_full_image=True
        )
        return float(m[0].mean(0).numpy()[mask].mean())

    t64 = best_of(ssim64, reps=1)
    diff = abs(ssim64() - masked_ssim(pred, gt, mask))
    total = sum(rows.values())

    RESULTS.mkdir(exist_ok=True)
    lines = [
        "## Evaluation metrics (`plantdreamer eval`)",
        "",
        "Command: `python benches/bench_eval.py`. Per view, 768 x 768 RGB, a disc mask covering",
        f"35% of the image; minimum of {REPS} runs (float64 SSIM: 1 run). Measured on a shared,",
        "loaded 2-core machine: other builds ran at the same time, so read the numbers as upper",
        "bounds.",
        "",
        "| metric | seconds per view |",
        "|---|---|",
        *[f"| {name} | {sec:.3f} |" for name, sec in rows.items()],
        f"| all metrics | {total:.3f} |",
        f"| masked SSIM in float64 (torchmetrics, for comparison) | {t64:.3f} |",
        "",
        f"SSIM is the whole cost. Float32 differs from float64 by {diff:.1e} here, and is what",
        "`masked_ssim` uses: torch's float64 convolution on the CPU is far slower. The paper's",
        f"120-view evaluation orbit adds about {120 * total:.0f} s of metrics to the renders.",
        "",
    ]
    (RESULTS / "eval.md").write_text("\n".join(lines))
    data = {"size": SIZE, "seconds": rows, "ssim_float64_seconds": t64, "ssim_abs_diff": diff}
    (RESULTS / "eval.json").write_text(json.dumps(data, indent=2) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
