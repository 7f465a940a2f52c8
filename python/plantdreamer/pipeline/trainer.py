"""The training loop: a ``Trainer`` holds the plants it trains together (each with its own
run state: model, optimiser, cameras, density control, log and folder) and one guidance that
owns their depth conditioning, and calls each at fixed points of a step:

    cameras -> the renders (one native call for every plant) -> the guidance on the batch
    -> its backward to the renders -> the rasterizer backward (one native call)
    -> per plant, on the step's pool: density.after_backward, Adam -> density.step_end
    -> checkpoints when due

and, after the last step, a final checkpoint (a run stopped during its export resumes with
the export). The trainer writes the checkpoints, each plant's and the group's noise state
(``group_noise.py``), and reads nothing back: a resume reads them through the same
``PlantCheckpoints`` and ``GroupNoise`` (``runs/``). Observers (``observer.py``: the
progress pictures, writers, profilers) hear the phases, the step ends and the checkpoints.

The step itself (``step/schedule.py``, drawn in docs/step.md) runs the plants as one batch
or, with ``overlap``, as two halves in flight, one half's host work beside the other's
device work; one plant is a batch of one, through the same calls. The schedule also holds
the rules of when the next step may start early and when a requested stop is honoured;
the trainer turns a stop signal into that request and writes the checkpoints. A plant
that fails (NaN, ...) is recorded: a group drops it and goes on, a single run raises it
once the step's updates are done.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

from plantdreamer.errors import RunInterrupted
from plantdreamer.guidance.base import Guidance
from plantdreamer.guidance.conditioned import ConditionedGuidance
from plantdreamer.pipeline import outputs
from plantdreamer.pipeline.model.gaussian_model import GaussianModel
from plantdreamer.pipeline.model.render import FrozenScene
from plantdreamer.pipeline.observer import TrainerObserver, notify
from plantdreamer.pipeline.progress import Progress
from plantdreamer.pipeline.settings.group_settings import GroupSettings
from plantdreamer.pipeline.state.checkpoint import CheckpointRecord, PlantCheckpoints
from plantdreamer.pipeline.state.group_noise import GroupNoise
from plantdreamer.pipeline.step.options import StepOptions
from plantdreamer.pipeline.step.plant import PlantRun
from plantdreamer.pipeline.step.schedule import StepSchedule
from plantdreamer.stop_signals import stop_signals_handled

__all__ = ["PlantRun", "RunInterrupted", "Trainer"]


class Trainer:
    def __init__(
        self,
        plants: list[PlantRun],
        guidance: Guidance,
        settings: GroupSettings,
        *,
        start: int,
        noise: GroupNoise,
        resume_folder: Path,
        options: StepOptions | None = None,
        isolate_failures: bool = False,
        observers: Sequence[TrainerObserver] = (),
    ) -> None:
        """Trains ``plants`` (each at step ``start``) with the group's ``guidance`` and
        ``settings``. ``noise``: where the guidance's noise state is saved with each
        checkpoint. ``resume_folder``: what ``RunInterrupted`` says to resume.
        ``options``: how the step runs (``StepOptions``, the same bits either way).
        ``isolate_failures``: a failing plant is recorded and dropped rather than raised."""
        options = options or StepOptions()
        from plantdreamer.guidance.base import NoGuidance

        self.plants, self.raw_guidance, self.settings = plants, guidance, settings
        self.start, self.noise, self.observers = start, noise, observers
        self.trains = not isinstance(guidance, NoGuidance)
        self.isolate = isolate_failures
        self.resume_folder = resume_folder
        for p in plants:
            p.state.timer.observers = observers
        # The step's one host pool: each plant's host work of a step, and each plant's
        # depth map of the next step beside it (so two tasks per plant at most).
        self.pool = ThreadPoolExecutor(2 * len(plants), thread_name_prefix="step")
        initials = [GaussianModel(p.state.initial) for p in plants]  # the depth maps' scenes
        self.guidance = ConditionedGuidance(
            guidance,
            [self._depth_renderer(m) for m in initials],
            [p.state.sampler.peek for p in plants],
            depth_rule=self.settings.sds.depth_rule,
            depth_size=self.settings.sds.depth_size,
            control_resize=self.settings.sds.control_resize,
            erosion_distance=self.settings.sds.erosion_distance,
            ahead=self.pool if options.depth_ahead else None,
        )
        self.schedule = StepSchedule(
            plants,
            self.settings,
            self.guidance,
            isolate_failures=isolate_failures,
            options=options,
            pool=self.pool,
            observers=observers,
        )

    def _depth_renderer(self, initial: GaussianModel):
        scene = FrozenScene(initial, "ED")  # its activations made once, not every step

        def render_depth(camera):
            depth, alpha, _ = scene.render([camera], self.settings.train.background)
            return depth, alpha

        return render_depth

    def alive(self) -> list[int]:
        return self.schedule.alive()

    @contextmanager
    def stops_handled(self) -> Iterator[None]:
        """Ctrl-C and SIGTERM inside the block ask the run to stop: the training loop writes
        its checkpoints at the next step boundary and raises ``RunInterrupted``; after the
        loop, ``stop_point`` raises it between two plants' exports."""
        with stop_signals_handled(self._request_stop):
            yield

    def stop_point(self) -> None:
        """Raises ``RunInterrupted`` if a stop was asked for (the plants' training is over
        and checkpointed: a resume only exports)."""
        if self.schedule.stop_requested:
            raise RunInterrupted(self.settings.train.steps, self.resume_folder)

    def run(self, show_progress: bool = True, on_step: Callable[[int], None] | None = None) -> None:
        """Steps from the plants' step to the last (inside ``stops_handled``, a stop writes a
        checkpoint at the next step boundary and raises ``RunInterrupted``), then writes the
        final checkpoint, so that a run stopped or killed during its export resumes with the
        export."""
        steps = self.settings.train.steps
        resumed_at_end = self.start == steps > 0  # its checkpoint at the last step exists
        progress = Progress(steps, self.start, show_progress)
        note = (
            "" if self.trains else "; no guidance: the steps only run density control and culling"
        )
        progress.note(
            f"initialised {sum(len(p.state.initial) for p in self.plants)} Gaussians{note}"
        )
        try:
            for step in range(self.start, steps):
                if self.schedule.stop_due():
                    self.checkpoint(step)
                    raise RunInterrupted(step, self.resume_folder)
                if self.trains:
                    loss: float | None = self.schedule.train_step(step)
                else:
                    loss = None
                    self.schedule.step_end(step, self.alive())
                progress.update(
                    step, loss, sum(len(self.plants[i].state.model) for i in self.alive())
                )
                notify(self.observers, "step_end", step, self.plants, loss)
                if (step + 1) % self.settings.train.checkpoint_every == 0 and step + 1 < steps:
                    self.checkpoint(step + 1)
                    progress.note(
                        f"checkpoint at step {step + 1}: progress pictures in {self._pictures()}"
                    )
                if on_step is not None:
                    on_step(step)
                if not self.alive():
                    break
            if not resumed_at_end:
                self.checkpoint(steps)
            for p in self.plants:
                p.state.step = steps
            progress.note(f"exporting, {self.settings.outputs.eval_views} renders per plant")
        finally:
            progress.close()
            self.guidance.close()
            self.pool.shutdown()
            notify(self.observers, "train_end")

    def _pictures(self) -> str:
        """Where the latest progress pictures are: each plant's folder."""
        if len(self.plants) == 1:
            return str(self.plants[0].out_dir)
        return f"each plant's folder under {self.resume_folder}"

    def _request_stop(self, signum, frame) -> None:
        if self.schedule.stop_requested:  # a second Ctrl-C or SIGTERM: stop now
            raise KeyboardInterrupt
        self.schedule.stop_requested = True

    def checkpoint(self, step: int) -> None:
        """Writes the group's noise state and each plant's ``checkpoint.pt`` (atomically) for
        a run continuing at ``step``, after the observers' ``checkpoint``; the previous
        ones go once all are written (``PlantCheckpoints``, ``GroupNoise``)."""
        alive = [self.plants[i] for i in self.alive()]
        for p in alive:
            p.state.step = step
        notify(self.observers, "checkpoint", step, alive)
        generator = self.raw_guidance.generator
        if generator is not None:  # so a resumed run draws the same noise
            self.noise.write(step, generator)
        for p in alive:
            with p.state.timer("checkpoint"):
                PlantCheckpoints(p.out_dir).write(CheckpointRecord.of(p.cfg, p.state))
                outputs.write_log_csv(p.out_dir / "log.csv", p.state.log_rows)
        for p in alive:
            PlantCheckpoints(p.out_dir).commit()
        self.noise.commit()
