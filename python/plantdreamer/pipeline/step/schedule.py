"""One training step of a trainer's plants: as one batch, or as two halves in flight.

One batch (``overlap`` off; a single plant is a batch of one): the plants render (one native call for all
of them, their scenes side by side on the rasterizer's pool), one guidance call runs on the
batch, its gradient goes back to the renders, the rasterizer backwards run (again one native
call), then each plant's Adam update and density control. Each plant's host work around
the native calls (its arguments, its share of the backward past them, gradient checks,
Adam, density statistics) runs on the trainer's host pool, one task per plant: numpy
and torch release the GIL, so B plants' host work spreads over the cores rather than
queueing on one thread (the same bits: each plant's operations are its own, in its own
order).

Two halves (``overlap`` on): the plants are split once, A the first
ceil(B/2) and B the rest. A launch queues a half's device work and returns at once
(``guidance/in_flight.py``); the host waits only when it needs that half's gradient:

    render A(k), launch A(k)   render B(k), launch B(k)   [device: A(k), then B(k)]
    wait A(k): rasterizer backward, Adam, step end A(k)   [device: B(k)]
    render A(k+1), launch A(k+1)                          [device: B(k), then A(k+1)]
    wait B(k): rasterizer backward, Adam, step end B(k)   [device: A(k+1)]
    render B(k+1), launch B(k+1) ...

What cannot overlap: a plant's render at step k+1 needs its own step k's Adam update and
density control, so a half's host work can only hide the other half's device work.

The run-ahead rule (``may_run_ahead``): A(k+1) is launched during step k except before a
checkpoint, a requested stop and the last step: there the pipeline drains, so a
checkpoint never holds work in flight. The stop rule (``stop_due``): a requested stop
(Ctrl-C, SIGTERM: ``stop_requested``) is honoured at the first step boundary with
nothing in flight, where the trainer checkpoints and stops. Every plant's work,
and every draw from the guidance's generator (A(k), B(k), A(k+1), ...), comes in the same
order whether or not A(k+1) went early, so draining (and resuming) changes no bits.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass
from time import perf_counter
from typing import Any

import torch
from torch.profiler import record_function

from plantdreamer.cameras import Camera
from plantdreamer.errors import PlantDreamerError
from plantdreamer.guidance.conditioned import ConditionedGuidance
from plantdreamer.guidance.in_flight import InFlight, launch_guidance
from plantdreamer.pipeline.model.render import RenderInputs, render_many
from plantdreamer.pipeline.observer import TrainerObserver, notify
from plantdreamer.pipeline.settings.group_settings import GroupSettings
from plantdreamer.pipeline.step.options import StepOptions
from plantdreamer.pipeline.step.plant import PlantRun
from plantdreamer.pipeline.step.update import update_plant


@dataclass
class _Launched:
    plants: list[int]
    cameras: list[Camera]
    renders: list[tuple[torch.Tensor, torch.Tensor, dict]]
    flight: InFlight
    # The renders came from one native call (one autograd node) with their inputs cut
    # from each plant's parameters (``RenderInputs``).
    cuts: list[RenderInputs]


class StepSchedule:
    """Runs each step of ``plants`` (module docstring): the overlap order, the run-ahead
    and the stop rule."""

    def __init__(
        self,
        plants: list[PlantRun],
        settings: GroupSettings,
        guidance: ConditionedGuidance,
        *,
        isolate_failures: bool,
        options: StepOptions,
        pool: Executor,
        observers: Sequence[TrainerObserver] = (),
    ) -> None:
        self.plants, self.settings, self.guidance = plants, settings, guidance
        self.isolate, self.options, self.observers = isolate_failures, options, observers
        self.stop_requested = False  # set by the trainer's signal handler
        cut = (len(plants) + 1) // 2 if settings.overlap else len(plants)
        self.halves = [list(range(cut)), list(range(cut, len(plants)))]
        self.pending: _Launched | None = None  # the first half of the next step, launched
        self._pool = pool  # the trainer's

    def may_run_ahead(self, step: int) -> bool:
        """Whether step + 1 may start during ``step``: not at a checkpoint (which must hold
        no work in flight), a requested stop or the end."""
        nxt = step + 1
        every = self.settings.train.checkpoint_every
        return nxt < self.settings.train.steps and nxt % every != 0 and not self.stop_requested

    def stop_due(self) -> bool:
        """A stop was requested and no work is in flight: stop before the next step (with a
        half in flight the stop waits a step, as the run-ahead stops)."""
        return self.stop_requested and self.pending is None

    def alive(self) -> list[int]:
        return [i for i, p in enumerate(self.plants) if p.error is None]

    def step_end(self, step: int, plants: list[int]) -> None:
        for i in plants:
            if self.plants[i].error is None:
                st = self.plants[i].state
                st.events += st.density.step_end(step, st.model, st.timer)

    def train_step(self, step: int) -> float:
        """Trains every live plant one step, density control's step end included; returns
        the step's loss (the mean over the plants trained)."""
        alive = set(self.alive())
        parts = [[i for i in half if i in alive] for half in self.halves]
        parts = [part for part in parts if part]
        more = step + 1 < self.settings.train.steps
        launched = []
        for j, part in enumerate(parts):
            if j == 0 and self.pending is not None:
                launched.append(self.pending)
                self.pending = None
            else:
                launched.append(self._launch(part, step, more))
        losses = []
        for j, work in enumerate(launched):
            losses.append(self._finish(work, step))
            self.step_end(step, work.plants)
            first = [i for i in work.plants if self.plants[i].error is None]
            if j + 1 < len(launched) and first and self.may_run_ahead(step):
                self.pending = self._launch(first, step + 1, step + 2 < self.settings.train.steps)
        sizes = [len(w.plants) for w in launched]
        return sum(v * n for v, n in zip(losses, sizes, strict=True)) / sum(sizes)

    @contextmanager
    def _timed(self, name: str, plants: Sequence[int]) -> Iterator[None]:
        """One phase of the step for ``plants`` (the part it ran for), and a named range of
        a profiler's timeline (benches/bench_throughput.py --trace). Its wall time is
        shared evenly among those plants: the calls run their scenes together, so each
        plant's figures are its share and a group's plants sum to the group's time."""
        notify(self.observers, "phase_start", name)
        t0 = perf_counter()
        with record_function(name):
            yield
        seconds = perf_counter() - t0
        for i in plants:
            self.plants[i].state.timer.totals[name] += seconds / len(plants)
        notify(self.observers, "phase_end", name, seconds)

    def _timer(self, plants: Sequence[int]) -> Callable[[str], AbstractContextManager[None]]:
        """``_timed`` for the phases of ``plants``, as the guidance's calls take a timer."""
        return lambda name: self._timed(name, plants)

    def _map(self, fn: Callable[[int], Any], items: Sequence[int]) -> list[Any]:
        """``[fn(i) for i in items]``, each plant's host work a task of the pool."""
        return list(self._pool.map(fn, items))

    def _launch(self, plants: list[int], step: int, more: bool) -> _Launched:
        group = [self.plants[i] for i in plants]
        cameras = [p.state.sampler.sample() for p in group]
        background = self.settings.train.background

        with self._timed("raster.forward", plants):
            models = [p.state.model for p in group]
            renders = []
            rendered, cuts = render_many(models, cameras, background, self._map)
            for p, r in zip(group, rendered, strict=True):
                if isinstance(r, Exception):
                    raise type(r)(f"{p.out_dir.name}: {r}")
                renders.append(r)
        batch = self._batch([r[0] for r in renders])
        flight = launch_guidance(
            self.guidance, batch, plants, cameras, step, more, self._timer(plants),
            sleeping_wait=self.options.sleeping_wait,
        )  # fmt: skip
        return _Launched(plants, cameras, renders, flight, cuts)

    def _batch(self, images: list[torch.Tensor]) -> torch.Tensor:
        """The renders as one [B, H, W, 3] tensor (without their graph: the guidance takes
        them detached), copied plant by plant on the pool. For a CUDA guidance it is pinned
        memory, so that the copy to the device is one DMA transfer with no staging copy
        (``transfer.to_device``'s ``pin_memory`` returns a pinned tensor as it is)."""
        pinned = self.guidance.device.type == "cuda"
        first = images[0]
        batch = torch.empty((len(images), *first.shape[1:]), dtype=first.dtype, pin_memory=pinned)

        def copy(k: int) -> None:
            batch[k : k + 1].copy_(images[k].detach())

        self._map(copy, range(len(images)))
        return batch

    def _finish(self, work: _Launched, step: int) -> float:
        """Waits for a launched half's gradient, back-propagates it through the rasterizer
        and updates its plants; a plant that fails is recorded (``isolate_failures``)."""
        group = [self.plants[i] for i in work.plants]
        with self._timed("guidance.wait", work.plants):
            out = work.flight.wait()
        with self._timed("raster.backward", work.plants):
            for p in group:
                optimizer = p.state.model.optimizer
                assert optimizer is not None  # the models are built with learning rates
                optimizer.zero_grad(set_to_none=True)
            images = [r[0] for r in work.renders]
            grads = out.grads

            # One node holds every render: one backward for all, to the cuts, then each
            # plant's share past them on the pool.
            torch.autograd.backward(images, [grads[k : k + 1] for k in range(len(group))])
            self._map(lambda k: work.cuts[k].backward(), range(len(group)))
        loss = out.loss
        # A non-finite loss fails the plants whose renders got non-finite gradients (all of
        # them when none did): one plant's NaN must not stop the others.
        culprits = set()
        if not math.isfinite(loss):
            culprits = {k for k in range(len(group)) if not bool(grads[k].isfinite().all())}
            culprits = culprits or set(range(len(group)))
        with self._timed("optimizer", work.plants):  # per-plant checks and Adam

            def update(k: int) -> PlantDreamerError | None:
                return update_plant(
                    group[k], step, loss, k in culprits, work.renders[k][2], work.cameras[k],
                    out.stats, k, len(group),
                )  # fmt: skip

            failures = self._map(update, range(len(group)))
            for p, failure in zip(group, failures, strict=True):
                if failure is not None:
                    p.error = str(failure)
        # A single run (not isolating) raises its first failure, in plant order.
        first_failure = next((f for f in failures if f is not None), None)
        if first_failure is not None and not self.isolate:
            raise first_failure
        return loss
