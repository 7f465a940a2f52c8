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
density control, so a half's host work can only hide the other half's device work. A(k+1)
is launched during step k except before a checkpoint, a requested stop and the last step:
there the pipeline drains, so a checkpoint never holds work in flight. Every plant's work,
and every draw from the guidance's generator (A(k), B(k), A(k+1), ...), comes in the same
order whether or not A(k+1) went early, so draining (and resuming) changes no bits.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch.profiler import record_function

from plantdreamer.cameras import Camera
from plantdreamer.errors import PlantDreamerError
from plantdreamer.guidance.conditioned import ConditionedGuidance
from plantdreamer.guidance.in_flight import InFlight, launch_guidance
from plantdreamer.pipeline.config import GenerateConfig
from plantdreamer.pipeline.model import GaussianModel, RenderInputs, render_many
from plantdreamer.pipeline.outputs import samples_cell
from plantdreamer.pipeline.run_state import RunState
from plantdreamer.pipeline.step_options import StepOptions


@dataclass
class PlantRun:
    """One plant of a trainer: its settings, state and folder; ``error`` once it failed."""

    cfg: GenerateConfig
    state: RunState
    out_dir: Path
    error: str | None = None


def resolve_overlap(setting: str, device: torch.device, plants: int) -> bool:
    """``overlap``'s ``auto``: on for a group whose guidance runs on CUDA. On the CPU the
    networks and the renders share the same cores, so the halves cannot hide each other."""
    if setting == "auto":
        return device.type == "cuda" and plants > 1
    return setting == "on"


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
    """Runs each step of ``plants`` (module docstring); ``run_ahead(step)`` says whether the
    first half of step + 1 may be launched during ``step`` (no checkpoint or stop between)."""

    def __init__(
        self,
        plants: list[PlantRun],
        guidance: ConditionedGuidance,
        *,
        overlap: bool,
        isolate_failures: bool,
        options: StepOptions,
        pool: Executor,
        run_ahead: Callable[[int], bool],
    ) -> None:
        self.plants, self.guidance = plants, guidance
        self.cfg = plants[0].cfg
        self.isolate, self.run_ahead, self.options = isolate_failures, run_ahead, options
        cut = (len(plants) + 1) // 2 if overlap else len(plants)
        self.halves = [list(range(cut)), list(range(cut, len(plants)))]
        self.pending: _Launched | None = None  # the first half of the next step, launched
        self._pool = pool  # the trainer's

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
        more = step + 1 < self.cfg.train.steps
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
            if j + 1 < len(launched) and first and self.run_ahead(step):
                self.pending = self._launch(first, step + 1, step + 2 < self.cfg.train.steps)
        sizes = [len(w.plants) for w in launched]
        return sum(v * n for v, n in zip(losses, sizes, strict=True)) / sum(sizes)

    @contextmanager
    def _timed(self, name: str) -> Iterator[None]:
        """One phase of the step, its wall time added to every live plant (the group's), and
        a named range of a profiler's timeline (benches/bench_throughput.py --trace)."""
        plants = self.alive()
        first = self.plants[plants[0]].state.timer.totals
        before = first[name]
        with self.plants[plants[0]].state.timer(name), record_function(name):
            yield
        for i in plants[1:]:
            self.plants[i].state.timer.totals[name] += first[name] - before

    def _map(self, fn: Callable[[int], Any], items: Sequence[int]) -> list[Any]:
        """``[fn(i) for i in items]``, each plant's host work a task of the pool."""
        return list(self._pool.map(fn, items))

    def _launch(self, plants: list[int], step: int, more: bool) -> _Launched:
        group = [self.plants[i] for i in plants]
        cameras = [p.state.sampler.sample() for p in group]
        background = self.cfg.train.background

        with self._timed("raster.forward"):
            models = [p.state.model for p in group]
            renders = []
            rendered, cuts = render_many(models, cameras, background, self._map)
            for p, r in zip(group, rendered, strict=True):
                if isinstance(r, Exception):
                    raise type(r)(f"{p.out_dir.name}: {r}")
                renders.append(r)
        batch = self._batch([r[0] for r in renders])
        flight = launch_guidance(
            self.guidance, batch, plants, cameras, step, more, self._timed,
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
        with self._timed("guidance.wait"):
            out = work.flight.wait()
        with self._timed("raster.backward"):
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
        with self._timed("optimizer"):  # per-plant checks and Adam, the group's time

            def update(k: int) -> PlantDreamerError | None:
                p = group[k]
                try:
                    check_finite_gradients(p.state.model, step)
                    if k in culprits:
                        raise PlantDreamerError(
                            f"loss became {loss} at step {step}; stopping (no output written)"
                        )
                except PlantDreamerError as exc:
                    return exc
                p.state.density.after_backward(step, work.renders[k][2], work.cameras[k])
                p.state.model.optimizer.step()  # type: ignore[union-attr]
                row = {"step": step, "loss": loss, "gaussians": len(p.state.model)}
                p.state.log_rows.append(row | plant_stats(out.stats, k, len(group)))
                return None

            failures = self._map(update, range(len(group)))
            for p, failure in zip(group, failures, strict=True):
                if failure is not None:
                    p.error = str(failure)
        # A single run (not isolating) raises its first failure, in plant order.
        first_failure = next((f for f in failures if f is not None), None)
        if first_failure is not None and not self.isolate:
            raise first_failure
        return loss


def plant_stats(stats: dict[str, float | list[float]], k: int, batch: int) -> dict[str, Any]:
    """The guidance's figures as the ``k``-th plant of a ``batch`` logs them: the batch's
    numbers as they are, and of each per-sample figure its own sample's only (one camera
    per plant and step), written as a log.csv cell."""
    own: dict[str, Any] = {}
    for key, value in stats.items():
        if isinstance(value, list):
            assert len(value) == batch, (key, len(value), batch)
            own[key] = samples_cell(value[k : k + 1])
        else:
            own[key] = value
    return own


def check_finite_gradients(model: GaussianModel, step: int) -> None:
    """Stops before a NaN or Inf gradient reaches the Gaussians through Adam (whose moments
    it would poison for every later step)."""
    for name, p in model.params.items():
        # A finite sum proves every value finite (one reduction, no mask); only a non-finite
        # one (a bad value, or rarely an overflowing sum) runs the exact test.
        if p.grad is None or math.isfinite(float(p.grad.sum())):
            continue
        if not bool(torch.isfinite(p.grad).all()):
            bad = int((~torch.isfinite(p.grad)).sum())
            raise PlantDreamerError(
                f"non-finite gradient on the Gaussians' {name} ({bad} values) at step {step}; "
                "stopping (no output written)"
            )
