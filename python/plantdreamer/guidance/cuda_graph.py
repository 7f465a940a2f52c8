"""One CUDA-graph replay for a call of fixed-shape tensors (ControlNet + UNet in SDS).

A full-size ControlNet + UNet call launches about two thousand small kernels. On an H100 the
GPU works about 18 ms of it while the host takes about 80 ms to launch them
(``benches/bench_networks.py``), so the step waits on Python, not on the GPU. Captured once
into a CUDA graph, each later call is a copy of the inputs into fixed buffers and one replay.

The graph is captured on the first call of each input signature (shapes, dtypes, device) and
replayed for calls with the same one; the same kernels run in the same order, so replays are
as deterministic as the eager call. The last ``KEPT_SIGNATURES`` graphs are kept: a group
trained as two half-batches of different sizes (an odd group) alternates two signatures
every step, and must not capture again on each call. If capture fails (an operation that
synchronises with the host, say), the call falls back to running eagerly, with one warning.
"""

from __future__ import annotations

import warnings
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

import torch

Signature = tuple[tuple[tuple[int, ...], torch.dtype, torch.device], ...]
# Two: the halves of a group in flight; a third (a plant failed) evicts the least recent.
KEPT_SIGNATURES = 2


def _make_room(graphs: OrderedDict[Any, Any]) -> None:
    """Drops the least recent graphs (freeing their memory pools) before a new capture."""
    while len(graphs) >= KEPT_SIGNATURES:
        graphs.popitem(last=False)


class GraphedCall:
    """``fn(*tensors) -> tensor`` replayed from a CUDA graph; no autograd (inference only)."""

    def __init__(self, fn: Callable[..., torch.Tensor], warmup: int = 2) -> None:
        self.fn = fn
        self.warmup = warmup
        # signature -> (graph, input buffers, output buffer), least recently used first
        self.graphs: OrderedDict[
            Signature, tuple[torch.cuda.CUDAGraph, tuple[torch.Tensor, ...], torch.Tensor]
        ] = OrderedDict()
        self.failed = False

    def __call__(self, *args: torch.Tensor) -> torch.Tensor:
        if self.failed or not all(a.is_cuda for a in args):
            return self.fn(*args)
        signature = tuple((tuple(a.shape), a.dtype, a.device) for a in args)
        if signature in self.graphs:
            self.graphs.move_to_end(signature)
        else:
            self._capture(args, signature)
            if self.failed:
                return self.fn(*args)
        graph, inputs, output = self.graphs[signature]
        for buffer, value in zip(inputs, args, strict=True):
            buffer.copy_(value)
        graph.replay()
        # A copy: the next replay (the other half's) overwrites the buffer.
        return output.clone()

    @torch.no_grad()
    def _capture(self, args: tuple[torch.Tensor, ...], signature: Signature) -> None:
        _make_room(self.graphs)
        inputs = tuple(a.detach().clone() for a in args)
        try:
            side = torch.cuda.Stream(device=args[0].device)
            side.wait_stream(torch.cuda.current_stream(args[0].device))
            with torch.cuda.stream(side):  # warm-up off the capture: lazy init, workspaces
                for _ in range(self.warmup):
                    self.fn(*inputs)
            torch.cuda.current_stream(args[0].device).wait_stream(side)
            graph = torch.cuda.CUDAGraph()
            with torch.cuda.graph(graph):
                output = self.fn(*inputs)
        except RuntimeError as exc:
            self.failed = True
            warnings.warn(
                f"CUDA graph capture failed ({exc}); running the networks eagerly", stacklevel=3
            )
            return
        self.graphs[signature] = (graph, inputs, output)


class GraphedAutogradCall:
    """``fn(*tensors) -> tensor`` whose forward and backward are each one CUDA-graph replay
    (``torch.cuda.make_graphed_callables``); for the VAE encoder, which SDS backpropagates
    through. Used when grad is enabled and the inputs' requires_grad match the capture;
    otherwise, off CUDA, or if capture failed, the call runs eagerly."""

    def __init__(self, fn: Callable[..., torch.Tensor], warmup: int = 3) -> None:
        self.fn = fn
        self.warmup = warmup
        self.graphs: OrderedDict[tuple, Callable[..., torch.Tensor]] = OrderedDict()
        self.failed = False

    def __call__(self, *args: torch.Tensor) -> torch.Tensor:
        usable = torch.is_grad_enabled() and any(a.requires_grad for a in args)
        if self.failed or not usable or not all(a.is_cuda for a in args):
            return self.fn(*args)
        signature = tuple((tuple(a.shape), a.dtype, a.device, a.requires_grad) for a in args)
        if signature in self.graphs:
            self.graphs.move_to_end(signature)
        else:
            _make_room(self.graphs)
            samples = tuple(a.detach().clone().requires_grad_(a.requires_grad) for a in args)
            try:
                graphed = torch.cuda.make_graphed_callables(
                    self.fn, samples, num_warmup_iters=self.warmup
                )
            except RuntimeError as exc:
                self.failed = True
                warnings.warn(
                    f"CUDA graph capture failed ({exc}); running the VAE eagerly", stacklevel=2
                )
                return self.fn(*args)
            self.graphs[signature] = graphed  # type: ignore[assignment]
        # The replayed backward writes the input gradient into a fixed buffer: the caller
        # must consume it (queue its next use) before the next call, as SDS's backward does.
        return self.graphs[signature](*args)
