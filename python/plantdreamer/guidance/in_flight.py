"""One guidance call queued on its device and read back later: the host's one wait.

``launch_guidance`` queues the whole device side of a guidance call for a batch of renders:
the renders' copy to the device (through pinned memory), the depth conditioning, the
networks, the backward to the renders, and the copies of the renders' gradient and of the
logged figures back into pinned host memory; then it records a CUDA event. Nothing on that
path waits for the device (no ``.item()``, ``float()``, ``bool()`` or copy into pageable
memory of a device tensor), so the host can render the other half of a group meanwhile.
``InFlight.wait`` is the one synchronisation: it waits for the event and hands back the
gradient and the figures. On the CPU every part runs at launch and ``wait`` returns at once.

The event is a blocking one (``StepOptions.sleeping_wait``): the waiting thread sleeps until the device
is done, where CUDA's default wait spins on a core for the whole of the networks' time. A
group's host work (rasterizer, Adam, depth conditioning) needs every core of the host, and
a spinning wait takes one from it; waking costs microseconds against steps of tens to
hundreds of milliseconds.

The backward is queued at launch, not at the wait: CUDA-graph replays keep their
activations and input gradients in fixed buffers (``cuda_graph.py``), so one half's
backward must be queued before the other half's forward overwrites them.
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import dataclass

import torch

from plantdreamer.cameras import Camera
from plantdreamer.guidance.base import PendingOutput
from plantdreamer.guidance.conditioned import ConditionedGuidance, Timer
from plantdreamer.guidance.transfer import to_device


@dataclass
class GuidanceResult:
    """``grads``: d loss / d render [B, H, W, 3] on the CPU, the loss scaled by B so each
    render gets its own plant's gradient; ``loss``: the batch's loss; ``stats``: logged."""

    grads: torch.Tensor
    loss: float
    stats: dict[str, float | list[float]]


class InFlight:
    """A launched guidance call; ``wait`` returns its ``GuidanceResult``."""

    def __init__(
        self,
        grads: torch.Tensor,
        figures: torch.Tensor,
        pending: PendingOutput,
        event: torch.cuda.Event | None,
    ) -> None:
        self._grads, self._figures, self._pending, self._event = grads, figures, pending, event

    def wait(self) -> GuidanceResult:
        if self._event is not None:
            self._event.synchronize()
        loss, *values = self._figures.tolist()
        out = self._pending.with_figures(values)
        return GuidanceResult(self._grads, loss, out.stats)


def launch_guidance(
    guidance: ConditionedGuidance,
    images: torch.Tensor,
    plants: Sequence[int],
    cameras: Sequence[Camera],
    step: int,
    more: bool,
    timer: Timer | None = None,
    *,
    sleeping_wait: bool = True,
) -> InFlight:
    """Queues the guidance of ``images`` [B, H, W, 3] (CPU renders of ``plants`` from
    ``cameras``) and its backward to them; ``sleeping_wait``: see the module docstring."""
    timed = timer or (lambda name: nullcontext())
    device = guidance.device
    leaf = to_device(images.detach(), device).requires_grad_(True)
    pending = guidance.launch(leaf, plants, cameras, step, more, timer)
    with timed("guidance.backward"):
        # The guidance's loss is a mean over the batch: each plant gets its own gradient.
        (pending.loss * len(plants)).backward()
    grads = leaf.grad
    assert grads is not None
    loss = pending.loss.detach().double().reshape(1)
    figures = pending.device_figures()
    readback = loss if figures is None else torch.cat([loss, figures.to(loss.device)])
    if device.type != "cuda":
        return InFlight(grads.cpu(), readback.cpu(), pending, None)
    host_grads = torch.empty(grads.shape, dtype=grads.dtype, pin_memory=True)
    host_grads.copy_(grads, non_blocking=True)
    host_figures = torch.empty(readback.shape, dtype=readback.dtype, pin_memory=True)
    host_figures.copy_(readback, non_blocking=True)
    event = torch.cuda.Event(blocking=sleeping_wait)
    event.record(torch.cuda.current_stream(device))
    return InFlight(host_grads, host_figures, pending, event)
