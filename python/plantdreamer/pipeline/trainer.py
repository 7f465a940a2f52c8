"""The training loop: a ``Trainer`` holds the plants it trains together (each with its own
run state: model, optimiser, cameras, density control, log and folder) and one guidance that
owns their depth conditioning, and calls each at fixed points of a step:

    cameras -> renders (one thread per plant) -> one guidance call on the batch
    -> backward to the renders -> rasterizer backwards (one thread per plant)
    -> per plant: density.after_backward, Adam, density.step_end -> checkpoints when due

One plant is a batch of one. In a group a plant that fails (NaN, ...) is recorded and
dropped; the others go on.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from plantdreamer.errors import PlantDreamerError
from plantdreamer.guidance.base import Guidance
from plantdreamer.guidance.conditioned import ConditionedGuidance
from plantdreamer.pipeline import outputs
from plantdreamer.pipeline.checkpoint import save_checkpoint
from plantdreamer.pipeline.config import GenerateConfig
from plantdreamer.pipeline.model import GaussianModel
from plantdreamer.pipeline.progress import Progress
from plantdreamer.pipeline.run_state import RunState
from plantdreamer.stop_signals import stop_signals_handled


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C during a run; a checkpoint at ``step`` was written before stopping."""

    def __init__(self, step: int, out_dir: Path) -> None:
        super().__init__(f"interrupted at step {step}")
        self.step, self.out_dir = step, out_dir


@dataclass
class PlantRun:
    """One plant of a trainer: its settings, state and folder; ``error`` once it failed."""

    cfg: GenerateConfig
    state: RunState
    out_dir: Path
    error: str | None = None


class Trainer:
    def __init__(
        self,
        plants: list[PlantRun],
        guidance: Guidance,
        *,
        depth_ahead: bool = True,
        isolate_failures: bool = False,
        out_dir: Path | None = None,
    ) -> None:
        """``isolate_failures``: a failing plant is recorded and dropped (a group) rather
        than raised (a single run). ``out_dir`` is the folder ``RunInterrupted`` names."""
        from plantdreamer.guidance.base import NoGuidance

        self.plants, self.raw_guidance = plants, guidance
        self.cfg = plants[0].cfg  # steps, background, sds settings: the same for all
        self.trains = not isinstance(guidance, NoGuidance)
        self.isolate = isolate_failures
        self.out_dir = out_dir if out_dir is not None else plants[0].out_dir
        initials = [GaussianModel(p.state.initial) for p in plants]  # the depth maps' scenes
        self.guidance = ConditionedGuidance(
            guidance,
            [self._depth_renderer(m) for m in initials],
            [p.state.sampler.peek for p in plants],
            depth_rule=self.cfg.sds.depth_rule,
            control_resize=self.cfg.sds.control_resize,
            erosion_distance=self.cfg.sds.erosion_distance,
            ahead=depth_ahead,
        )
        self._pool = ThreadPoolExecutor(len(plants)) if len(plants) > 1 else None
        self._stop_requested = False

    def _depth_renderer(self, initial: GaussianModel):
        def render_depth(camera):
            with torch.no_grad():
                depth, alpha, _ = initial.render([camera], self.cfg.train.background, "ED")
            return depth, alpha

        return render_depth

    def alive(self) -> list[int]:
        return [i for i, p in enumerate(self.plants) if p.error is None]

    def run(self, show_progress: bool = True, on_step: Callable[[int], None] | None = None) -> None:
        """Steps from the plants' step to the last; Ctrl-C (or SIGTERM) writes a checkpoint
        at the next step boundary and raises ``RunInterrupted``."""
        steps, first = self.cfg.train.steps, self.plants[0].state
        progress = Progress(steps, first.step, show_progress)
        note = (
            "" if self.trains else "; no guidance: the steps only run density control and culling"
        )
        progress.note(
            f"initialised {sum(len(p.state.initial) for p in self.plants)} Gaussians{note}"
        )
        try:
            with stop_signals_handled(self._request_stop):
                for step in range(first.step, steps):
                    if self._stop_requested:
                        self.checkpoint(step)
                        raise RunInterrupted(step, self.out_dir)
                    loss = self.train_step(step) if self.trains else None
                    for i in self.alive():
                        st = self.plants[i].state
                        st.events += st.density.step_end(step, st.model, st.timer)
                    progress.update(
                        step, loss, sum(len(self.plants[i].state.model) for i in self.alive())
                    )
                    if (step + 1) % self.cfg.train.checkpoint_every == 0 and step + 1 < steps:
                        self.checkpoint(step + 1)
                    if on_step is not None:
                        on_step(step)
                    if not self.alive():
                        break
            for p in self.plants:
                p.state.step = steps
            progress.note(f"exporting, {self.cfg.outputs.eval_views} renders per plant")
        finally:
            progress.close()
            self.guidance.close()
            if self._pool is not None:
                self._pool.shutdown()

    def _request_stop(self, signum, frame) -> None:
        if self._stop_requested:  # a second Ctrl-C or SIGTERM: stop now
            raise KeyboardInterrupt
        self._stop_requested = True

    @contextmanager
    def _timed(self, name: str, plants: list[int]) -> Iterator[None]:
        """One phase of the step, its wall time added to every plant in it."""
        first = self.plants[plants[0]].state.timer.totals
        before = first[name]
        with self.plants[plants[0]].state.timer(name):
            yield
        for i in plants[1:]:
            self.plants[i].state.timer.totals[name] += first[name] - before

    def _map(self, fn: Callable[[int], Any], plants: list[int]) -> list[Any]:
        if self._pool is None or len(plants) == 1:
            return [fn(i) for i in plants]
        return list(self._pool.map(fn, plants))

    def train_step(self, step: int) -> float:
        plants = self.alive()
        group = [self.plants[i] for i in plants]
        cameras = [p.state.sampler.sample() for p in group]
        background = self.cfg.train.background

        def render(k: int):
            return group[k].state.model.render([cameras[k]], background)

        with self._timed("render", plants):
            renders = self._map(render, list(range(len(group))))
        images = [r[0] for r in renders]
        batch = images[0] if len(images) == 1 else torch.cat(images)
        leaf = batch.detach().requires_grad_(True)
        more = step + 1 < self.cfg.train.steps
        out = self.guidance(leaf, plants, cameras, step, more, lambda n: self._timed(n, plants))
        with self._timed("backward", plants):
            for p in group:
                optimizer = p.state.model.optimizer
                assert optimizer is not None  # the models are built with learning rates
                optimizer.zero_grad(set_to_none=True)
            # The guidance's loss is a mean over the batch: each plant gets its own gradient.
            (out.loss if len(group) == 1 else out.loss * len(group)).backward()
            grads = leaf.grad
            assert grads is not None
            self._map(lambda k: images[k].backward(grads[k : k + 1]), list(range(len(group))))
        loss = float(out.loss.detach())
        # A non-finite loss fails the plants whose renders got non-finite gradients (all of
        # them when none did): one plant's NaN must not stop the others.
        culprits = set()
        if not math.isfinite(loss):
            culprits = {k for k in range(len(group)) if not bool(grads[k].isfinite().all())}
            culprits = culprits or set(range(len(group)))
        with self._timed("optimizer", plants):  # per-plant checks and Adam, the group's time
            for k, p in enumerate(group):
                try:
                    check_finite_gradients(p.state.model, step)
                    if k in culprits:
                        raise PlantDreamerError(
                            f"loss became {loss} at step {step}; stopping (no output written)"
                        )
                except PlantDreamerError as exc:
                    if not self.isolate:
                        raise
                    p.error = str(exc)
                    continue
                p.state.density.after_backward(step, renders[k][2], cameras[k])
                p.state.model.optimizer.step()  # type: ignore[union-attr]
                row = {"step": step, "loss": loss, "gaussians": len(p.state.model), **out.stats}
                p.state.log_rows.append(row)
        return loss

    def checkpoint(self, step: int) -> None:
        """Writes each plant's ``checkpoint.pt`` (atomically) for a run continuing at ``step``."""
        generator = self.raw_guidance.generator
        noise = None if generator is None else generator.get_state()
        for i in self.alive():
            p = self.plants[i]
            with p.state.timer("checkpoint"):
                p.state.step = step
                record: dict[str, Any] = {
                    "config": p.cfg.to_dict(),
                    **p.state.state_dict(),
                    # The guidance's noise generator, so a resumed run draws the same noise.
                    "guidance": noise,
                }
                save_checkpoint(p.out_dir, record)
                outputs.write_log_csv(p.out_dir / "log.csv", p.state.log_rows)


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
