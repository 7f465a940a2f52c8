"""The training loop: a ``Trainer`` holds the run's state (model, cameras, density control),
the guidance with its depth conditioning, and calls each at fixed points of a step:

    camera -> render -> guidance (depth conditioning inside) -> backward
    -> density.after_backward -> Adam -> density.step_end -> checkpoint when due
"""

from __future__ import annotations

import math
from collections.abc import Callable
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


class Trainer:
    def __init__(
        self,
        cfg: GenerateConfig,
        state: RunState,
        guidance: Guidance,
        out_dir: Path,
        *,
        depth_ahead: bool = True,
    ) -> None:
        from plantdreamer.guidance.base import NoGuidance

        self.cfg, self.state, self.out_dir = cfg, state, out_dir
        self.raw_guidance = guidance
        self.trains = not isinstance(guidance, NoGuidance)
        self._initial = GaussianModel(state.initial)  # fixed: the depth maps' scene
        self.guidance = ConditionedGuidance(
            guidance,
            self._render_depth,
            state.sampler.peek,
            depth_rule=cfg.sds.depth_rule,
            control_resize=cfg.sds.control_resize,
            ahead=depth_ahead,
        )
        self._stop_requested = False

    def _render_depth(self, camera):
        with torch.no_grad():
            depth, alpha, _ = self._initial.render([camera], self.cfg.train.background, "ED")
        return depth, alpha

    def run(self, show_progress: bool = True, on_step: Callable[[int], None] | None = None) -> None:
        """Steps from the state's step to the last; Ctrl-C (or SIGTERM) writes a checkpoint
        at the next step boundary and raises ``RunInterrupted``."""
        cfg, state = self.cfg, self.state
        steps = cfg.train.steps
        progress = Progress(steps, state.step, show_progress)
        progress.note(
            f"initialised {len(state.initial)} Gaussians"
            + (
                ""
                if self.trains
                else "; no guidance: the steps only run density control and culling"
            )
        )
        try:
            with stop_signals_handled(self._request_stop):
                for step in range(state.step, steps):
                    if self._stop_requested:
                        self.checkpoint(step)
                        raise RunInterrupted(step, self.out_dir)
                    loss = self.train_step(step) if self.trains else None
                    state.events += state.density.step_end(step, state.model, state.timer)
                    progress.update(step, loss, len(state.model))
                    if (step + 1) % cfg.train.checkpoint_every == 0 and step + 1 < steps:
                        self.checkpoint(step + 1)
                    if on_step is not None:
                        on_step(step)
            state.step = steps
            views = cfg.outputs.eval_views
            progress.note(f"exporting {len(state.model)} Gaussians, {views} renders")
        finally:
            progress.close()
            self.guidance.close()

    def _request_stop(self, signum, frame) -> None:
        if self._stop_requested:  # a second Ctrl-C or SIGTERM: stop now
            raise KeyboardInterrupt
        self._stop_requested = True

    def train_step(self, step: int) -> float:
        cfg, state, timer = self.cfg, self.state, self.state.timer
        model = state.model
        camera = state.sampler.sample()
        with timer("render"):
            image, _, meta = model.render([camera], cfg.train.background)
        out = self.guidance(image, camera, step, more=step + 1 < cfg.train.steps, timer=timer)
        optimizer = model.optimizer
        assert optimizer is not None  # the model is built with learning rates
        with timer("backward"):
            optimizer.zero_grad(set_to_none=True)
            out.loss.backward()
        check_finite_gradients(model, step)
        state.density.after_backward(step, meta, camera)
        with timer("optimizer"):
            optimizer.step()
        loss = float(out.loss.detach())
        if not math.isfinite(loss):
            raise PlantDreamerError(
                f"loss became {loss} at step {step}; stopping (no output written)"
            )
        state.log_rows.append({"step": step, "loss": loss, "gaussians": len(model), **out.stats})
        return loss

    def checkpoint(self, step: int) -> None:
        """Writes ``checkpoint.pt`` (atomically) for a run continuing at ``step``."""
        state = self.state
        with state.timer("checkpoint"):
            state.step = step
            generator = self.raw_guidance.generator
            record: dict[str, Any] = {
                "config": self.cfg.to_dict(),
                **state.state_dict(),
                # The guidance's noise generator, so a resumed run draws the same noise.
                "guidance": None if generator is None else generator.get_state(),
            }
            save_checkpoint(self.out_dir, record)
            outputs.write_log_csv(self.out_dir / "log.csv", state.log_rows)


def check_finite_gradients(model: GaussianModel, step: int) -> None:
    """Stops before a NaN or Inf gradient reaches the Gaussians through Adam (whose moments
    it would poison for every later step)."""
    for name, p in model.params.items():
        if p.grad is not None and not bool(torch.isfinite(p.grad).all()):
            bad = int((~torch.isfinite(p.grad)).sum())
            raise PlantDreamerError(
                f"non-finite gradient on the Gaussians' {name} ({bad} values) at step {step}; "
                "stopping (no output written)"
            )
