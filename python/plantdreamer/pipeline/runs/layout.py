"""Where a run's plants live, what it claims and where its record is kept: the three
layouts of the one lifecycle (``entry.generate_plants``).

- ``PlantAlone``: one plant written into ``out`` itself (``generate``). Its record is kept
  in memory: the folder's checkpoint (or run.json) holds its config, and a resume finds it
  there.
- ``FolderPerPlant``: ``out/<species>-s<seed>/`` per plant and the group's record,
  ``out/group.json`` (``generate --seeds``, ``plantdreamer.generate(seeds=...)``).
- ``GivenFolders``: a dataset unit's plant folders, named by them. The record is the
  dataset's manifest (the caller's), so nothing is written beside the folders.

A layout says how a run's record is made and found, what it locks (and, with
``overwrite``, clears: only what the run writes), where the record is saved, and where the
noise state of each of its trainers is kept (``group_noise.py``).
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

from plantdreamer.errors import CheckpointError, InputError
from plantdreamer.output_folder import Owned, claim_folder, tree
from plantdreamer.output_locks import check_not_inside_held
from plantdreamer.pipeline.runs.record import (
    DONE,
    GROUP_FILE,
    PlantEntry,
    RunRecord,
    plant_name,
)
from plantdreamer.pipeline.settings.config import GenerateConfig
from plantdreamer.pipeline.state.run_outputs import (
    CHECKPOINT_NAME,
    NOISE_NAME,
    RUN_OUTPUTS,
    is_finished,
)


@dataclass(frozen=True)
class PlantAlone:
    """One plant in ``out`` itself."""

    def new_record(self, cfgs: Sequence[GenerateConfig], out: Path) -> RunRecord:
        if len(cfgs) != 1:
            raise InputError(f"a plant alone is one config, not {len(cfgs)}: name a group")
        return RunRecord.new(list(cfgs), [out], [plant_name(cfgs[0])])

    def found_record(self, out: Path) -> RunRecord:
        """The plant's record from its folder: its latest checkpoint's config, or a finished
        run's (``done``)."""
        from plantdreamer.pipeline.state.checkpoint import PlantCheckpoints, read_config

        if is_finished(out):
            import json

            config = GenerateConfig.from_dict(json.loads((out / "run.json").read_text())["config"])
            return RunRecord([PlantEntry(plant_name(config), config, out, DONE)])
        starts = PlantCheckpoints(out).starts() if out.is_dir() else {}
        if not starts:
            raise CheckpointError(
                f"no checkpoint to resume from: {out / CHECKPOINT_NAME} does not exist"
            )
        config = read_config(out / starts[max(starts)])
        return RunRecord([PlantEntry(plant_name(config), config, out)])

    def claim(
        self, stack: ExitStack, out: Path, record: RunRecord, *, overwrite: bool, resume: bool
    ) -> None:
        check_not_inside_held(out, f"output folder {out}")  # in use: said first
        if not resume and not overwrite and (out / CHECKPOINT_NAME).is_file():
            raise InputError(
                f"{out} holds a checkpoint of an earlier run; continue it with --resume "
                f"{out}, pass --overwrite to start afresh, or choose another folder"
            )
        stack.enter_context(
            claim_folder(out, overwrite=overwrite, owned=RUN_OUTPUTS, allow_existing=resume,
                         inputs=_inputs(record.plants))
        )  # fmt: skip

    def save(self, record: RunRecord, out: Path) -> None:
        """Nothing to save: the folder's checkpoint and run.json are the record."""

    def noise_folder(self, out: Path, part: Sequence[PlantEntry]) -> Path:
        return out

    def noise_folders(self, out: Path, part: Sequence[PlantEntry]) -> list[Path]:
        return [out]


@dataclass(frozen=True)
class FolderPerPlant:
    """``out/<name>/`` per plant, ``out/group.json`` the record."""

    def new_record(self, cfgs: Sequence[GenerateConfig], out: Path) -> RunRecord:
        names = [plant_name(c) for c in cfgs]
        return RunRecord.new(list(cfgs), [out / n for n in names], names)

    def found_record(self, out: Path) -> RunRecord:
        return RunRecord.read(out)

    def claim(
        self, stack: ExitStack, out: Path, record: RunRecord, *, overwrite: bool, resume: bool
    ) -> None:
        """The group's folder (with ``overwrite``: its record and the plants' outputs,
        those of plants that failed their checks aside), then each plant's folder."""
        owned: list[Owned] = [GROUP_FILE, NOISE_NAME]
        for entry in record.plants:
            if entry.error is None:  # a plant whose inputs failed is left untouched
                owned += tree(entry.name, *RUN_OUTPUTS)
        stack.enter_context(
            claim_folder(out, overwrite=overwrite, owned=owned, allow_existing=resume,
                         inputs=_inputs(record.plants))
        )  # fmt: skip
        _claim_plants(stack, record)

    def save(self, record: RunRecord, out: Path) -> None:
        record.write(out)

    def noise_folder(self, out: Path, part: Sequence[PlantEntry]) -> Path:
        return out

    def noise_folders(self, out: Path, part: Sequence[PlantEntry]) -> list[Path]:
        return [out]


@dataclass(frozen=True)
class GivenFolders:
    """A dataset unit's plants, each in the folder given (named by it). The dataset holds
    its own lock on its folder and keeps the record (its manifest)."""

    folders: tuple[Path, ...]

    def new_record(self, cfgs: Sequence[GenerateConfig], out: Path) -> RunRecord:
        if len(cfgs) != len(self.folders):
            raise InputError(f"{len(cfgs)} configs for {len(self.folders)} plant folders")
        return RunRecord.new(list(cfgs), list(self.folders), [f.name for f in self.folders])

    def found_record(self, out: Path) -> RunRecord:
        raise InputError("a dataset unit resumes from the configs it is given")

    def claim(
        self, stack: ExitStack, out: Path, record: RunRecord, *, overwrite: bool, resume: bool
    ) -> None:
        _claim_plants(stack, record)

    def save(self, record: RunRecord, out: Path) -> None:
        """Nothing to save: the dataset's manifest is the record."""

    def noise_folder(self, out: Path, part: Sequence[PlantEntry]) -> Path:
        """A unit's trainer keeps its noise in its first plant's folder."""
        return part[0].folder

    def noise_folders(self, out: Path, part: Sequence[PlantEntry]) -> list[Path]:
        return [entry.folder for entry in part]


Layout = PlantAlone | FolderPerPlant | GivenFolders


def found_layout(out: Path) -> PlantAlone | FolderPerPlant:
    """The layout of the run a resume continues in ``out``: a group by its record."""
    return FolderPerPlant() if (out / GROUP_FILE).is_file() else PlantAlone()


def _claim_plants(stack: ExitStack, record: RunRecord) -> None:
    """Locks each plant's folder (made if new) for the run; nothing is deleted here."""
    for entry in record.plants:
        if entry.error is None:
            stack.enter_context(
                claim_folder(entry.folder, owned=RUN_OUTPUTS, allow_existing=True,
                             inputs=_inputs([entry]))
            )  # fmt: skip


def _inputs(plants: Sequence[PlantEntry]) -> list[str]:
    return [p.config.source.pointcloud for p in plants if p.config.source.pointcloud is not None]
