"""Acceptance of issue 7 end to end: one SDS step through the rasterizer reaches the Gaussians.

Uses ``plantdreamer.rasterization`` (gsplat's API).
"""

import numpy as np
import torch

from plantdreamer import rasterization
from plantdreamer.cameras import orbit, stack
from plantdreamer.guidance.sds import StableDiffusionDepthGuidance
from plantdreamer.guidance.tiny import tiny_models


def test_sds_gradient_reaches_gaussian_colours_and_positions():
    g = torch.Generator().manual_seed(0)
    n = 200
    means = (torch.rand(n, 3, generator=g) - 0.5).requires_grad_(True)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1)
    scales = torch.full((n, 3), 0.05)
    opacities = torch.full((n,), 0.8)
    colors = torch.rand(n, 3, generator=g).requires_grad_(True)
    camera = orbit(3.0, 20.0, 30.0, 60.0, 32, 32)
    viewmats, ks = stack([camera])
    renders, _alphas, _ = rasterization(
        means,
        quats,
        scales,
        opacities,
        colors,
        torch.from_numpy(viewmats),
        torch.from_numpy(ks),
        32,
        32,
    )
    assert renders.shape == (1, 32, 32, 3)
    guidance = StableDiffusionDepthGuidance(components=tiny_models(), resolution=64, device="cpu")
    depth = torch.rand(1, 1, 64, 64, generator=g)
    guidance(renders, depth, [camera], step=0).loss.backward()
    for name, param in (("colours", colors), ("positions", means)):
        assert param.grad is not None, name
        assert torch.isfinite(param.grad).all(), name
        assert np.count_nonzero(param.grad.numpy()) > 0, name
