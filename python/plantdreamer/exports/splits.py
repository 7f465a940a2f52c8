"""Seeded train/val/test splits of a dataset by plant: every view of a plant falls in the
same split, so no plant is seen in training and evaluation both.

A plant's split depends only on its own id, the seed and the ratios: SHA-256 of the seed and
the id, read as a number u in [0, 1), falls in one of the intervals the ratios cut [0, 1)
into (splits with a zero share cut none and get no plant). So the split is the same on
every machine and Python version, whatever order plants were listed or finished in, and a
plant keeps its split when the dataset grows: a plant evaluated in one version of a dataset
is not trained on in the next.

Each plant draws its own u, so the ratios are expected shares: every species is split in
them on average, and a small dataset's counts can differ from them (two beans and two kale
at 0.5/0.25/0.25 and seed 0 draw both kale for train). A quota per species would move
plants between splits as plants are added, which the draw avoids; ``exact_splits.py`` is
that quota, for those who want the counts (``--split-mode exact``). Small datasets can draw
no plant for a split by chance (5 plants at 0.8/0.1/0.1: 59% of seeds give val none):
``check_splits`` makes that an error naming the counts, or a warning with ``allow_empty``;
``species_counts`` gives the per-split count of each species, and ``species_gaps`` warns of
a species missing from a split where it would be expected.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterable, Mapping

from plantdreamer.errors import InputError

SPLITS = ("train", "val", "test")
DEFAULT_RATIOS = (0.8, 0.1, 0.1)
DEFAULT_SEED = 0
# How plants are split: each draws its split (the ratios are expected shares), or exact
# counts per species (``exact_splits.py``).
SPLIT_MODES = ("draw", "exact")
DEFAULT_MODE = "draw"


def parse_ratios(text: str) -> tuple[float, float, float]:
    """``"0.8,0.1,0.1"`` (or ``"8,1,1"``: any non-negative weights) as ratios summing to 1."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) and v >= 0 for v in values):
        raise InputError(
            f"--split must be TRAIN,VAL,TEST (three non-negative numbers), got {text!r}"
        )
    total = sum(values)
    if not math.isfinite(total):
        raise InputError(f"--split weights overflow when summed, got {text!r}")
    if total <= 0:
        raise InputError(f"--split needs a positive weight, got {text!r}")
    return (values[0] / total, values[1] / total, values[2] / total)


def plant_draw(plant_id: str, seed: int) -> float:
    """The plant's number in [0, 1): SHA-256 of the seed and its id."""
    digest = hashlib.sha256(f"{seed}\0{plant_id}".encode()).digest()
    return int.from_bytes(digest[:8], "big") / 2.0**64


def split_of(plant_id: str, ratios: tuple[float, float, float], seed: int) -> str:
    """The split of one plant: where its draw falls among the ratios' intervals."""
    u = plant_draw(plant_id, seed)
    shares = [(split, r) for split, r in zip(SPLITS, ratios, strict=True) if r > 0]
    edge = 0.0
    for split, share in shares[:-1]:
        edge += share
        if u < edge:
            return split
    return shares[-1][0]  # the last split with a share takes the rest (no rounding gap)


def split_plants(
    plant_ids: Iterable[str],
    ratios: tuple[float, float, float] = DEFAULT_RATIOS,
    seed: int = DEFAULT_SEED,
) -> dict[str, list[str]]:
    """{"train": [...], "val": [...], "test": [...]}, each list sorted by id."""
    if not any(r > 0 for r in ratios):
        raise InputError("--split needs a positive weight")
    cut: dict[str, list[str]] = {split: [] for split in SPLITS}
    for plant_id in sorted(set(plant_ids)):
        cut[split_of(plant_id, ratios, seed)].append(plant_id)
    return cut


def check_splits(
    splits: Mapping[str, list[str]],
    ratios: tuple[float, float, float],
    allow_empty: bool = False,
) -> list[str]:
    """Refuses a split with a share but no plant (one line naming the counts); with
    ``allow_empty``, returns that line as a warning instead."""
    empty = [s for s, r in zip(SPLITS, ratios, strict=True) if r > 0 and not splits[s]]
    if not empty:
        return []
    counts = ", ".join(f"{len(splits[s])} {s}" for s in SPLITS)
    shares = ",".join(f"{r:g}" for r in ratios)
    line = (
        f"split {' and '.join(empty)} drew no plant ({counts} of "
        f"{sum(len(v) for v in splits.values())} plants at --split {shares})"
    )
    if allow_empty:
        return [line]
    raise InputError(
        f"{line}: add plants, change --split, --split-seed or --split-mode, or pass "
        "--allow-empty-split"
    )


def species_counts(
    splits: Mapping[str, list[str]], species: Mapping[str, str]
) -> dict[str, dict[str, int]]:
    """Per split, the number of plants of each species (sorted by species)."""
    counts: dict[str, dict[str, int]] = {}
    for split in SPLITS:
        names = sorted(species.get(p, "?") for p in splits[split])
        counts[split] = {name: names.count(name) for name in sorted(set(names))}
    return counts


def species_gaps(
    splits: Mapping[str, list[str]],
    species: Mapping[str, str],
    ratios: tuple[float, float, float],
) -> list[str]:
    """Warnings for a species with enough plants to expect one in a split (its count times
    the split's share at least 1) that drew none there: the draw is per plant, not a quota."""
    totals: dict[str, int] = {}
    for ids in splits.values():
        for p in ids:
            totals[species.get(p, "?")] = totals.get(species.get(p, "?"), 0) + 1
    counts = species_counts(splits, species)
    lines = []
    for split, share in zip(SPLITS, ratios, strict=True):
        for name, n in sorted(totals.items()):
            if n * share >= 1 and not counts[split].get(name):
                lines.append(
                    f"no {name} plant drew {split} ({n} {name} plants at a share of {share:g}; "
                    "another --split-seed gives another draw)"
                )
    return lines
