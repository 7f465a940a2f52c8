"""The one entry of every generation, one plant or a group, fresh or resumed: what the
``generate`` command and the Python API's ``plantdreamer.generate`` call. A plant alone
writes into ``out`` itself (``run.py``), a group one folder per plant under it
(``group.py``); a resume finds which ``out`` holds by its ``group.json``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from plantdreamer.errors import InputError, PlantsFailed
from plantdreamer.pipeline.config import GenerateConfig
from plantdreamer.pipeline.export import RunResult
from plantdreamer.pipeline.group import GROUP_FILE, GroupResult, generate_group
from plantdreamer.pipeline.run import generate

__all__ = ["PlantsFailed", "generate_plants"]  # PlantsFailed: plantdreamer.errors'


def generate_plants(
    cfgs: list[GenerateConfig] | None,
    out: str | Path,
    *,
    group: bool = False,
    resume: bool = False,
    changes: dict[str, Any] | None = None,
    overwrite: bool = False,
    show_progress: bool = True,
) -> list[RunResult]:
    """Trains ``cfgs`` into ``out``: one plant in ``out``, or with ``group`` (plants of
    several seeds) each in its own folder under ``out``. ``resume`` (``cfgs`` None)
    continues the run in ``out``, a plant or a group; ``changes`` are the settings given
    again, which a plant checks against its checkpoint and a group takes none of.

    Returns each finished plant's result, in folder-name order for a group; when plants
    of a group fail, raises ``PlantsFailed`` naming each once the others are written."""
    out = Path(out)
    if resume:
        if (out / GROUP_FILE).is_file():
            if changes:
                raise InputError("a group resumes with the settings it started with")
            return _finished(generate_group(None, out, resume=True, show_progress=show_progress))
        return [generate(None, out, resume=True, changes=changes, show_progress=show_progress)]
    if cfgs is None:
        raise InputError("a config is needed unless resuming")
    if not group:
        return [generate(cfgs[0], out, overwrite=overwrite, show_progress=show_progress)]
    return _finished(generate_group(cfgs, out, overwrite=overwrite, show_progress=show_progress))


def _finished(result: GroupResult) -> list[RunResult]:
    done = [run for _, run in sorted(result.done.items())]
    if result.failed:
        failures = "; ".join(f"{name}: {error}" for name, error in sorted(result.failed.items()))
        raise PlantsFailed(
            f"{len(result.failed)} of {len(result.done) + len(result.failed)} plants failed "
            f"({failures}); see {result.out_dir / GROUP_FILE}",
            done,
        )
    return done
