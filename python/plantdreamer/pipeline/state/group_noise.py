"""The guidance's noise state of the plants trained together, saved once per trainer.

Plants trained together draw their SDS noise from one generator (the guidance's), so its
state is the group's, not any plant's. ``OUT/noise.pt`` holds it for each trainer that
writes into that folder (a group's parts train one after another, each with a guidance of
its own): its plants' names and the state at each checkpoint step it still keeps. It is
written beside the plants' checkpoints and kept as they are: a trainer's previous step
stays until every plant holds the next (``commit``), so a resume at the plants' common
step finds its noise. Once the plants have trained to the end, a resume only exports:
the entry goes (``remove``), and the file with the last one.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from plantdreamer.checkpoint_io import read_checkpoint, write_checkpoint
from plantdreamer.errors import CheckpointError, InputError
from plantdreamer.pipeline.state.run_outputs import NOISE_NAME

FORMAT = 1
# Bytes of a saved torch generator state, by device: the CPU's Mersenne Twister, CUDA's
# Philox (seed and offset).
_STATE_BYTES = {5056: "cpu", 16: "cuda"}


class GroupNoise:
    """The noise entry, in ``folder``'s file, of the trainer of ``plants`` (by name)."""

    def __init__(self, folder: Path, plants: Sequence[str]) -> None:
        self.path = Path(folder) / NOISE_NAME
        self.plants = list(plants)

    def write(self, step: int, generator: Any) -> None:
        """The state at ``step``, beside the steps kept until ``commit``."""
        saved = self._load()
        entry = self._own(saved)
        if entry is None:
            entry = {"plants": self.plants, "steps": {}}
            saved["trainers"].append(entry)
        entry["steps"][str(step)] = noise_state(generator)
        write_checkpoint(self.path, saved)

    def commit(self) -> None:
        """Every plant holds the latest step: the earlier ones go."""
        saved = self._load()
        entry = self._own(saved)
        if entry is not None and len(entry["steps"]) > 1:
            latest = max(entry["steps"], key=int)
            entry["steps"] = {latest: entry["steps"][latest]}
            write_checkpoint(self.path, saved)

    def remove(self) -> None:
        """This trainer's entry goes (its plants need no more noise); the file if empty."""
        if not self.path.is_file():
            return
        saved = self._load()
        saved["trainers"] = [t for t in saved["trainers"] if t["plants"] != self.plants]
        if saved["trainers"]:
            write_checkpoint(self.path, saved)
        else:
            self.path.unlink(missing_ok=True)

    def read(self, step: int) -> dict[str, Any] | None:
        """The state at ``step`` of a trainer that held every one of ``plants`` (a part that
        resumes together trained together), or None when the file holds none."""
        if not self.path.is_file():
            return None
        for entry in self._load()["trainers"]:
            if set(self.plants) <= set(entry["plants"]) and str(step) in entry["steps"]:
                return entry["steps"][str(step)]
        return None

    def _load(self) -> dict[str, Any]:
        if not self.path.is_file():
            return {"format": FORMAT, "trainers": []}
        saved = read_checkpoint(self.path)
        trainers = saved.get("trainers")
        if saved.get("format") != FORMAT or not isinstance(trainers, list):
            raise CheckpointError(f"{self.path}: not a noise state of this plantdreamer")
        return saved

    def _own(self, saved: dict[str, Any]) -> dict[str, Any] | None:
        """This trainer's entry (its plants, in its order), if the file holds one."""
        return next((t for t in saved["trainers"] if t["plants"] == self.plants), None)


def noise_state(generator: Any) -> dict[str, Any]:
    """A generator's saved state (``{"guidance": None}``: the guidance draws no noise)."""
    if generator is None:
        return {"guidance": None}
    return {"guidance": generator.get_state(), "guidance_device": generator.device.type}


def restore_noise_state(generator: Any, saved: dict[str, Any], where: Path) -> None:
    """Sets the guidance's noise generator to a saved state, so the resumed run draws the
    same noise. A state drawn on another kind of device (a CPU run resumed on CUDA, or a
    checkpoint from before the CUDA generator moved onto the GPU) cannot go on with the
    same noise: one line says so rather than torch's error."""
    state = saved.get("guidance")
    if state is None:
        return
    if generator is None:
        raise InputError(f"{where}: it holds a guidance's noise state; this guidance has none")
    here = generator.device.type
    # Checkpoints without the device name are told apart by the state's size.
    saved_on = saved.get("guidance_device") or _STATE_BYTES.get(int(state.numel()), "unknown")
    if saved_on != here:
        raise CheckpointError(
            f"{where}: its SDS noise was drawn on {saved_on} and this run's guidance draws on "
            f"{here}; resume with the device it was made on (--device), or start again with "
            "--overwrite"
        )
    try:
        generator.set_state(state)
    except (RuntimeError, TypeError) as exc:
        raise CheckpointError(f"{where}: damaged guidance noise state ({exc})") from exc
