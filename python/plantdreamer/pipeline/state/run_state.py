"""Everything a run needs to continue: one object, one ``state_dict``.

A checkpoint is ``RunState.state_dict()`` plus the config and the guidance's noise state;
``RunState.resumed`` rebuilds the state from one, so a resumed run continues with the same
bits as one that never stopped. Every draw of a run comes from a generator of its own (the
sampler's, density control's, the guidance's noise), never from torch's global one, so the
global state is neither seeded nor saved (checkpoints that hold it still load).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from plantdreamer.gaussians import Gaussians
from plantdreamer.pipeline.model.density import DensityControl
from plantdreamer.pipeline.model.gaussian_model import GaussianModel
from plantdreamer.pipeline.model.sampler import CameraSampler
from plantdreamer.pipeline.progress import PhaseTimer
from plantdreamer.pipeline.settings.config import GenerateConfig
from plantdreamer.pointcloud import NormalizeTransform

_GAUSSIAN_FIELDS = ("means", "quats", "log_scales", "opacity_logits", "sh", "labels")


@dataclass
class RunState:
    step: int  # the next step to run
    initial: Gaussians  # the Gaussians the run started from (depth conditioning, run.json)
    model: GaussianModel
    sampler: CameraSampler
    density: DensityControl
    transform: NormalizeTransform  # restores the input frame at export
    source_counts: dict[str, int]
    label_fields: dict[str, str | None] | None
    log_rows: list[dict[str, Any]]
    events: list[dict[str, Any]]
    timer: PhaseTimer

    @classmethod
    def fresh(cls, cfg: GenerateConfig, show_progress: bool) -> RunState:
        """Step 0: the source loaded and turned into the initial Gaussians."""
        from plantdreamer.pipeline.model.source import initial_gaussians, load_source

        timer = PhaseTimer()
        with timer("prepare"):
            source = load_source(cfg.source, cfg.seed, surface=cfg.init.init_shape == "surface")
            g = initial_gaussians(cfg.init, source, cfg.seed)
        if cfg.outputs.labels:  # the masks' limits, now rather than after the last step
            from plantdreamer.labels import check_mask_limits

            check_mask_limits(g.labels)
        if show_progress and cfg.source.pointcloud is not None:
            found = source.label_fields or {}
            print(
                f"labels: class from {found.get('label') or 'none'}, "
                f"instance from {found.get('instance') or 'none'}",
                file=sys.stderr,
            )
        return cls(
            step=0,
            initial=g,
            model=GaussianModel(g, cfg.train.lr),
            sampler=_sampler(cfg),
            density=DensityControl(cfg.density, cfg.seed, len(g)),
            transform=source.transform,
            source_counts=source.counts,
            label_fields=source.label_fields if source.labels is not None else None,
            log_rows=[],
            events=[],
            timer=timer,
        )

    @classmethod
    def resumed(cls, cfg: GenerateConfig, state: dict[str, Any]) -> RunState:
        """The state a checkpoint holds (KeyError, TypeError, ... when it is damaged)."""
        initial = Gaussians(**{k: v.numpy() for k, v in state["initial"].items() if v is not None})
        run = cls(
            step=0,
            initial=initial,
            model=GaussianModel(initial, cfg.train.lr),
            sampler=_sampler(cfg),
            density=DensityControl(cfg.density, cfg.seed, len(initial)),
            transform=NormalizeTransform.from_dict(state["transform"]),
            source_counts={},
            label_fields=None,
            log_rows=[],
            events=[],
            timer=PhaseTimer(),
        )
        run.load_state_dict(state)
        return run

    def state_dict(self) -> dict[str, Any]:
        g = self.initial
        return {
            "step": self.step,
            "model": self.model.state_dict(),
            "initial": {
                k: None if getattr(g, k) is None else torch.from_numpy(getattr(g, k).copy())
                for k in _GAUSSIAN_FIELDS
            },
            "transform": self.transform.to_dict(),
            "source_counts": self.source_counts,
            "label_fields": self.label_fields,
            "sampler": self.sampler.state(),
            "density": self.density.state_dict(),
            "log_rows": self.log_rows,
            "events": self.events,
            "timings": dict(self.timer.totals),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Everything but the initial Gaussians (given at construction)."""
        self.step = int(state["step"])
        self.model.load_state_dict(state["model"])
        self.sampler.set_state(state["sampler"])
        self.density.load_state_dict(state["density"])
        self.transform = NormalizeTransform.from_dict(state["transform"])
        self.source_counts = state["source_counts"]
        self.label_fields = state.get("label_fields")
        self.log_rows, self.events = state["log_rows"], state["events"]
        self.timer = PhaseTimer(state["timings"])

    def label_summary(self, final: Gaussians, exported: bool) -> dict[str, Any] | None:
        """Where the labels came from and the Gaussians per class / instance count."""
        from plantdreamer.labels import class_counts

        first, last = self.initial.labels, final.labels
        if first is None or last is None:
            return None
        return {
            "fields": self.label_fields,
            "classes": {"initial": class_counts(first[:, 0]), "final": class_counts(last[:, 0])},
            "instances": {
                "initial": int(np.unique(first[first[:, 1] >= 0, 1]).size),
                "final": int(np.unique(last[last[:, 1] >= 0, 1]).size),
            },
            "exported": exported,
        }


def _sampler(cfg: GenerateConfig) -> CameraSampler:
    train = cfg.train
    return CameraSampler(train.cameras, train.render_size, cfg.seed, train.elevation_sampling)
