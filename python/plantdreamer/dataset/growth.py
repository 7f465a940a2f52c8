"""Growth series in a dataset spec: ``growth`` given as a list (``[0.25, 0.5, 1]``) or a
range (``"0.25-1/4"``: 4 stages evenly from 0.25 to 1; parts may be joined by commas)
makes each seed's plant at every stage, its id ending ``-g<stage>``; each stage but the
first has ``growth-since`` set to the stage before it, so its traits.json marks the leaves
that are new since then. A single number is a setting like any other (no series)."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from plantdreamer.errors import InputError

_RANGE = re.compile(r"\s*([0-9]*\.?[0-9]+)\s*-\s*([0-9]*\.?[0-9]+)\s*/\s*([0-9]+)\s*")
_NUMBER = re.compile(r"\s*[0-9]*\.?[0-9]+\s*")
MAX_STAGES = 1000  # stages in one series


@dataclass(frozen=True)
class SeriesStage:
    """A stage of a series: the settings it sets and the suffix of its plants' ids."""

    settings: dict[str, Any] = field(default_factory=dict)
    suffix: str = ""


def growth_series(settings: dict[str, Any], where: str) -> list[SeriesStage]:
    """The stages of a group whose settings give ``growth`` as a list or range (it leaves
    ``settings``), else one stage that changes nothing."""
    given = settings.get("growth")
    if not isinstance(given, list | str):
        return [SeriesStage()]
    if "growth-since" in settings:
        raise InputError(
            f"spec: {where}: a growth series sets growth-since itself (each stage's "
            "previous one); leave it out"
        )
    stages = _stages(settings.pop("growth"), where)
    previous: list[float | None] = [None, *stages[:-1]]
    return [
        SeriesStage({"growth": s, "growth-since": p}, f"-g{s:g}")
        for s, p in zip(stages, previous, strict=True)
    ]


def _stages(given: list | str, where: str) -> list[float]:
    what = f"spec: {where}: 'growth'"
    values: list[float] = []
    if isinstance(given, list):
        if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in given):
            raise InputError(f'{what} must be a stage, a list of stages or a range like "0.25-1/4"')
        values = [float(v) for v in given]
    else:
        for part in given.split(","):
            if _NUMBER.fullmatch(part):
                values.append(float(part))
            elif match := _RANGE.fullmatch(part):
                low, high, count = float(match[1]), float(match[2]), int(match[3])
                if not 1 <= count <= MAX_STAGES or high < low:
                    raise InputError(
                        f"{what}: {part.strip()!r} is no range of stages (A-B/N: N stages "
                        f"from A up to B, N in 1..{MAX_STAGES})"
                    )
                values += np.linspace(low, high, count).round(6).tolist() if count > 1 else [high]
            else:
                raise InputError(
                    f"{what}: {part.strip()!r} is no stage or range (0.5, or 0.25-1/4: 4 "
                    "stages from 0.25 to 1)"
                )
    stages = sorted(set(values))
    if not stages:
        raise InputError(f"{what} names no stage")
    if len(stages) > MAX_STAGES:
        raise InputError(f"{what} names {len(stages)} stages, more than {MAX_STAGES}")
    return stages
