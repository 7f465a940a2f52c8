"""The tests' view of a group run through the one entry (``generate_plants`` with a folder
per plant and failures recorded): the results by name, the failed ones' errors."""

from __future__ import annotations

from typing import Any

from plantdreamer.pipeline import FolderPerPlant, PlantResult, generate_plants


def group(cfgs: Any, out: Any, **kw: Any) -> list[PlantResult]:
    """``generate --seeds``: a folder per plant under ``out``, a plant's failure recorded."""
    return generate_plants(cfgs, out, layout=FolderPerPlant(), failures="record", **kw)


def done(results: list[PlantResult]) -> dict[str, PlantResult]:
    return {r.name: r for r in results if r.done}


def failed(results: list[PlantResult]) -> dict[str, str | None]:
    return {r.name: r.error for r in results if r.status == "failed"}


def resumed_from(results: list[PlantResult]) -> dict[str, int]:
    return {r.name: r.resumed_from for r in results if r.resumed_from is not None}
