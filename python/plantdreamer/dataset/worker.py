"""The long-lived worker of a dataset run: one per plant slot (with SDS, per GPU), a process
of the local pool (``local_worker.py``) or a Ray actor (``ray_workers.py``), which keeps
its diffusion models loaded from one plant (or packed group) to the next.

A ``PlantWorker`` holds its CPUs and GPU for the whole run and trains the units the driver
hands it, one at a time. ``ModelCache`` keeps the networks of the last guidance it built
(base model, ControlNet and LoRA, on the worker's device) and builds each later unit's
guidance on them when the config names the same models, so the weights are read, moved
and LoRA-merged once per worker instead of once per plant. Every unit still gets a
guidance of its own (its seed's noise generator, its timestep schedule, its prompts), so a
plant's bytes do not depend on what the worker ran before. One set of networks is kept:
a unit naming other models replaces it.

The driver cannot interrupt a worker's running call, so a unit asks its ``Board`` (the
driver's side of the run, seen from the worker: ``tasks.Board``) whether the driver wants to
stop (from its step hook, at most every ``STOP_POLL_S``) and, if so, interrupts its own
main thread as Ctrl-C would: the trainer writes its checkpoints at the next step boundary
and stops.
"""

from __future__ import annotations

import _thread
import time
from typing import Any

from plantdreamer.dataset.tasks import Board, run_unit

STOP_POLL_S = 0.5


class ModelCache:
    """The networks of the last SDS guidance built, and how often they were loaded."""

    def __init__(self) -> None:
        self.key: tuple[Any, ...] | None = None
        self.parts: Any = None
        self.loads = 0

    def guidance_for(self, group: Any) -> Any:
        """The guidance of plants' shared settings (``GroupSettings``, resolved)."""
        from plantdreamer.pipeline.settings.runtime import build_guidance

        if group.sds.guidance == "none":
            return build_guidance(group)
        key = model_key(group.sds)
        if key == self.key:
            return build_guidance(group, components=self.parts)
        self.key = self.parts = None  # the old networks go before the new ones load
        guidance = build_guidance(group)
        self.key, self.parts = key, guidance.parts  # type: ignore[attr-defined]
        self.loads += 1
        return guidance


def model_key(sds: Any) -> tuple[Any, ...]:
    """What the loaded networks depend on: which weights, their precision and device."""
    return (sds.base_model, sds.controlnet, sds.lora, sds.network_dtype, sds.vae_dtype,
            sds.device)  # fmt: skip


class StopCheck:
    """A step hook that turns the driver's stop request into Ctrl-C in this process."""

    def __init__(self, board: Board) -> None:
        self.board = board
        self.next_poll = 0.0

    def __call__(self, step: int) -> None:
        now = time.monotonic()
        if now < self.next_poll:
            return
        self.next_poll = now + STOP_POLL_S
        if self.board.stopping():
            _thread.interrupt_main()  # the trainer's Ctrl-C handler: checkpoint, then stop


class PlantWorker:
    """Trains units (one plant, or a packed group) one after another."""

    def __init__(self) -> None:
        self.cache = ModelCache()

    def run(self, unit: dict[str, Any], board: Board) -> dict[str, dict[str, Any]]:
        """Each plant's record, by plant id."""
        return run_unit(unit, board, self.cache.guidance_for, StopCheck(board))

    def loads(self) -> int:
        return self.cache.loads
