"""A plant of a trainer (its settings, run state and folder), and the settings that a
trainer's plants share."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from plantdreamer.guidance.config import SdsConfig
from plantdreamer.pipeline.config import GenerateConfig
from plantdreamer.pipeline.group_record import check_shared
from plantdreamer.pipeline.outputs import OutputsConfig
from plantdreamer.pipeline.run_state import RunState
from plantdreamer.pipeline.train_config import TrainConfig


@dataclass
class PlantRun:
    """One plant of a trainer: its settings, state and folder; ``error`` once it failed."""

    cfg: GenerateConfig
    state: RunState
    out_dir: Path
    error: str | None = None


@dataclass(frozen=True)
class GroupSettings:
    """What a trainer's plants share: every section of their settings but the per-plant
    ones (``group_record.PER_PLANT``: seed and point cloud), which stay in each plant's
    ``cfg``. The trainer, the step and the loop read the group's settings here."""

    train: TrainConfig
    sds: SdsConfig
    outputs: OutputsConfig

    @classmethod
    def of(cls, plants: Sequence[PlantRun]) -> GroupSettings:
        """The plants' shared settings; InputError when they differ beyond PER_PLANT."""
        cfgs = [p.cfg for p in plants]
        check_shared(cfgs)
        return cls(cfgs[0].train, cfgs[0].sds, cfgs[0].outputs)

    @property
    def overlap(self) -> bool:
        """Whether the plants train as two halves in flight (``runtime.resolve_overlap``
        decided ``auto`` before the trainer was built)."""
        if self.train.overlap not in ("on", "off"):
            raise RuntimeError("overlap is decided by runtime.resolve_overlap first")
        return self.train.overlap == "on"
