"""Exact splits (``--split-mode exact``): counts within one plant of the shares, for every
species and for the whole dataset, where the per-plant draw (``splits.py``) gives the shares
only on average.

The counts: species s with n plants would have n * share plants in each split, in general
not whole. Each species' count in a split is that number rounded down or up, each species'
counts add up to its plants, and each split's count over all species is its own total
share rounded down or up (a controlled rounding of the species x split table, which always
exists for a table of two dimensions: Cox and Ernst, 1982). It is found as a flow: each
species' plants left over after rounding down go, one per split at most, to splits whose
total is short, the largest remainders first.

The plants: a species' plants in the order of their draws (SHA-256 of the seed and the id,
as the draw mode's), cut into train, then val, then test at its counts. So the split is the
same on every machine whatever order plants were listed in, and a plant moves only when
its species' counts change (moving its cuts) or a new plant of its species falls before it
in the order and pushes it across a cut: growing a dataset of
three species one plant at a time to 60 at 0.8/0.1/0.1 moved at most 3 plants at an
addition, 34 in all (``tests/test_exact_splits.py``), where the draw mode moves none.

``make_splits`` splits in either mode.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from fractions import Fraction

from plantdreamer.errors import InputError
from plantdreamer.exports.splits import SPLIT_MODES, SPLITS, plant_draw, split_plants


def make_splits(
    species_of: Mapping[str, str], ratios: tuple[float, float, float], seed: int, mode: str
) -> dict[str, list[str]]:
    """The splits of the plants (id -> species) in ``mode``: each plant's draw
    (``splits.split_plants``), or exact counts (``exact_split``)."""
    if mode not in SPLIT_MODES:
        raise InputError(f"split mode must be one of {', '.join(SPLIT_MODES)}, got {mode!r}")
    if not any(r > 0 for r in ratios):
        raise InputError("--split needs a positive weight")
    if mode == "exact":
        return exact_split(species_of, ratios, seed)
    return split_plants(species_of, ratios, seed)


def split_rule(ratios: tuple[float, float, float], seed: int, mode: str) -> str:
    """How the splits were made, in a sentence (the dataset's card)."""
    shares = " / ".join(f"{s} {r:.4g}" for s, r in zip(SPLITS, ratios, strict=True))
    if mode == "exact":
        return (
            f"Splits are by plant, at {shares} exactly (`--split-mode exact`): every species' "
            "count in each split, and each split's total, is within one plant of its share "
            f"(seed {seed} orders each species' plants)."
        )
    return (
        f"Splits are by plant, at expected shares of {shares} (seed {seed}): each plant draws "
        "its split, so a small dataset's counts can differ from the shares "
        "(`--split-mode exact` gives counts within one plant of them, per species)."
    )


def exact_split(
    species_of: Mapping[str, str], ratios: tuple[float, float, float], seed: int
) -> dict[str, list[str]]:
    """{"train": [...], "val": [...], "test": [...]} of the plants (id -> species), each list
    sorted by id, with the counts of ``exact_counts``."""
    by_species: dict[str, list[str]] = {}
    for plant_id in sorted(species_of):
        by_species.setdefault(species_of[plant_id], []).append(plant_id)
    counts = exact_counts({name: len(ids) for name, ids in by_species.items()}, ratios)
    cut: dict[str, list[str]] = {split: [] for split in SPLITS}
    for name, ids in by_species.items():
        ordered = sorted(ids, key=lambda i: (plant_draw(i, seed), i))
        start = 0
        for split, count in zip(SPLITS, counts[name], strict=True):
            cut[split] += ordered[start : start + count]
            start += count
    return {split: sorted(ids) for split, ids in cut.items()}


def exact_counts(
    plants: Mapping[str, int], ratios: tuple[float, float, float]
) -> dict[str, list[int]]:
    """Each species' plants per split (``plants``: species -> plants): within one plant of
    its shares, and each split's total within one plant of the whole dataset's share."""
    weights = [Fraction(r).limit_denominator(10**6) for r in ratios]  # 0.7, not 0.7000...01
    shares = [w / sum(weights) for w in weights]
    names = sorted(plants)
    wanted = {s: [plants[s] * share for share in shares] for s in names}
    counts = {s: [math.floor(a) for a in wanted[s]] for s in names}
    # What is left to place: a plant per species short of its total, a place per split
    # short of its total's floor (must be filled) or ceiling (may be).
    left = {s: plants[s] - sum(counts[s]) for s in names}
    totals = [sum(wanted[s][k] for s in names) for k in range(len(shares))]
    placed = [sum(counts[s][k] for s in names) for k in range(len(shares))]
    must = [math.floor(t) - p for t, p in zip(totals, placed, strict=True)]
    may = [math.ceil(t) - p for t, p in zip(totals, placed, strict=True)]
    # Each species' splits with a remainder, the largest first (then in SPLITS order).
    edges = {s: _by_remainder(wanted[s]) for s in names}
    extra = _flow(names, left, edges, must)
    extra = _flow(names, left, edges, may, extra)
    for s in names:
        if sum(extra[s]) != left[s]:  # a controlled rounding always exists: never reached
            raise RuntimeError(f"no exact split of {dict(plants)} at {ratios}")
        counts[s] = [c + e for c, e in zip(counts[s], extra[s], strict=True)]
    return counts


def _by_remainder(wanted: list[Fraction]) -> list[int]:
    """The splits whose wanted count is not whole, the largest remainder first."""
    return sorted((k for k, a in enumerate(wanted) if a % 1), key=lambda k: (-(wanted[k] % 1), k))


def _flow(
    names: list[str],
    left: dict[str, int],
    edges: dict[str, list[int]],
    capacity: list[int],
    extra: dict[str, list[int]] | None = None,
) -> dict[str, list[int]]:
    """The leftover plants placed (``extra``: species -> one 0/1 per split) so that each
    split takes at most ``capacity`` of them, as many as can be: augmenting paths from
    species with plants left, in name order, to splits with room, through species that
    give up a place for another of their splits (a species takes one plant per split at
    most: its count stays within one of its share)."""
    extra = extra or {s: [0] * len(capacity) for s in names}

    def room(k: int) -> bool:
        return sum(extra[s][k] for s in names) < capacity[k]

    def augment(s: str, seen: set[int]) -> bool:
        for k in edges[s]:
            if extra[s][k] or k in seen:
                continue
            seen.add(k)
            if room(k):
                extra[s][k] = 1
                return True
            for other in names:  # a species holding k moves to another of its splits
                if extra[other][k] and augment_from(other, k, seen):
                    extra[s][k] = 1
                    return True
        return False

    def augment_from(s: str, k: int, seen: set[int]) -> bool:
        extra[s][k] = 0
        if augment(s, seen):
            return True
        extra[s][k] = 1
        return False

    for s in names:
        while sum(extra[s]) < left[s] and augment(s, set()):
            pass
    return extra
