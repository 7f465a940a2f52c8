"""The settings a trainer's plants share, what their one guidance is made of, and the most
plants one trainer holds."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from plantdreamer.errors import InputError
from plantdreamer.guidance.config import SdsConfig
from plantdreamer.pipeline.outputs import OutputsConfig
from plantdreamer.pipeline.settings.config import PER_PLANT, GenerateConfig, check_shared
from plantdreamer.pipeline.settings.train_config import TrainConfig

__all__ = [
    "MAX_GROUP_PLANTS",
    "PER_PLANT",
    "GroupSettings",
    "check_group_size",
    "parse_group_seeds",
]

# The most plants one trainer holds (each keeps its model, optimiser and renders in memory
# from step 0); dataset's --plants-per-gpu has the same limit.
MAX_GROUP_PLANTS = 64


@dataclass(frozen=True)
class GroupSettings:
    """What a trainer's plants share: every section of their settings but the per-plant
    ones (``config.PER_PLANT``: seed and point cloud), which stay in each plant's ``cfg``,
    and what the group's guidance is made of: the plant named in its prompts and the seed
    of its noise. The trainer, the step, the loop and the guidance read them here."""

    train: TrainConfig
    sds: SdsConfig
    outputs: OutputsConfig
    prompt_name: str  # the plant in the prompts (``bean`` for ``bean-released``)
    # The guidance's noise seed: the first plant's (a plant alone draws from its own seed,
    # and a group's noise is its first plant's, as every version has made it).
    noise_seed: int

    @classmethod
    def of(cls, cfgs: Sequence[GenerateConfig]) -> GroupSettings:
        """The plants' shared settings; InputError when they differ beyond ``PER_PLANT``."""
        check_shared(cfgs)
        first = cfgs[0]  # the shared settings, read from any plant
        return cls(first.train, first.sds, first.outputs, first.source.plant_name(), first.seed)

    @property
    def overlap(self) -> bool:
        """Whether the plants train as two halves in flight (``runtime.resolve_overlap``
        decided ``auto`` before the trainer was built)."""
        if self.train.overlap not in ("on", "off"):
            raise RuntimeError("overlap is decided by runtime.resolve_overlap first")
        return self.train.overlap == "on"


def check_group_size(plants: int, what: str = "a group") -> None:
    if plants > MAX_GROUP_PLANTS:
        raise InputError(
            f"{what} of {plants} plants is more than one trainer holds (at most "
            f"{MAX_GROUP_PLANTS}, as --plants-per-gpu); train them as several groups, or "
            "with `plantdreamer dataset`"
        )


def parse_group_seeds(text: str) -> list[int]:
    """``--seeds`` (``plantdreamer.seeds``' grammar), no more than one trainer holds."""
    from plantdreamer.seeds import TooManySeeds, parse_seeds

    try:
        return parse_seeds(text, MAX_GROUP_PLANTS)
    except TooManySeeds as many:
        raise InputError(
            f"--seeds {text} makes a group of {many.count} plants; one trainer holds at most "
            f"{MAX_GROUP_PLANTS} (as --plants-per-gpu): train them as several groups, or with "
            "`plantdreamer dataset --seeds`"
        ) from None
