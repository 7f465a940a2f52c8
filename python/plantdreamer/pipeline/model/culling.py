"""Large-Gaussian culling: remove Gaussians whose volume is an outlier (paper Sec. 3.3)."""

from __future__ import annotations

import numpy as np
import torch

from plantdreamer import _core


def large_gaussian_mask(
    log_scales: torch.Tensor, c: float, volume: str = "log"
) -> tuple[torch.Tensor, dict]:
    """True where V > mean(V) + c std(V) (Bessel std); non-finite volumes are always culled.

    ``volume="log"``: V = sqrt(sum_i exp(s_i)^2) on the log-scales s, the paper's formula.
    ``volume="double-exp"``: V = sqrt(sum_i exp(exp(s_i))^2), what the authors' released code
    computes (it applies the formula's exp to scales that are already activated).
    Computed in float64 by the native core.
    """
    s = log_scales.detach().cpu()
    if volume == "double-exp":
        s = torch.exp(s.double())
    elif volume != "log":
        raise ValueError(f"unknown culling volume {volume!r}")
    mask, stats = _core.large_gaussian_mask(
        np.ascontiguousarray(s.numpy(), dtype=np.float32), float(c)
    )
    return torch.from_numpy(mask), stats
