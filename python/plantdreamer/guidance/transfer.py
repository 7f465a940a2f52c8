"""Host-to-GPU copies of renders and depth maps through pinned (page-locked) memory.

A copy from pageable memory makes the driver stage it through its own pinned buffer while
the host waits; from pinned memory it is one DMA transfer queued on the stream, so the host
goes on preparing the next work. Renders need their gradient back on the CPU, where the
rasterizer's backward runs: ``_PinnedCopy`` returns it there.
"""

from __future__ import annotations

import torch


class _PinnedCopy(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x: torch.Tensor, device: torch.device) -> torch.Tensor:  # type: ignore[override]
        ctx.source = x.device
        return x.pin_memory().to(device, non_blocking=True)

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> tuple[torch.Tensor, None]:  # type: ignore[override]
        return grad.to(ctx.source), None


def to_device(x: torch.Tensor, device: torch.device) -> torch.Tensor:
    """``x`` on ``device``; CPU-to-CUDA copies go through pinned memory (differentiable)."""
    if device.type != "cuda" or x.device.type != "cpu":
        return x.to(device)
    if x.requires_grad:
        return _PinnedCopy.apply(x, device)
    return x.pin_memory().to(device, non_blocking=True)
