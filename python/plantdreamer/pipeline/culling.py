"""Large-Gaussian culling: remove Gaussians whose volume is an outlier (paper Sec. 3.3)."""

from __future__ import annotations

import numpy as np
import torch

from plantdreamer import _core


def large_gaussian_mask(log_scales: torch.Tensor, c: float) -> tuple[torch.Tensor, dict]:
    """True where V = sqrt(sum_i exp(s_i)^2) > mean(V) + c std(V) (Bessel std).

    Computed in float64 by the native core; non-finite volumes are always culled.
    """
    s = np.ascontiguousarray(log_scales.detach().cpu().numpy(), dtype=np.float32)
    mask, stats = _core.large_gaussian_mask(s, float(c))
    return torch.from_numpy(mask), stats
