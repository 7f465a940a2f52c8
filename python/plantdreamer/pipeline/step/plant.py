"""A plant of a trainer: its settings, run state and folder."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from plantdreamer.pipeline.settings.config import GenerateConfig
from plantdreamer.pipeline.state.run_state import RunState


@dataclass
class PlantRun:
    """One plant of a trainer: its settings, state and folder; ``error`` once it failed."""

    cfg: GenerateConfig
    state: RunState
    out_dir: Path
    error: str | None = None
