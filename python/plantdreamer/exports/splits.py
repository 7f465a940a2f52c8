"""Seeded train/val/test splits of a dataset by plant: every view of a plant falls in the
same split, so no plant is seen in training and evaluation both.

Plants are ordered by a hash of the seed and their id (SHA-256, so the order is the same on
every machine and Python version and does not depend on the order plants were listed or
finished), then cut by the ratios: round(n * train) plants to train, round(n * val) to val,
the rest to test.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterable

from plantdreamer.errors import InputError

SPLITS = ("train", "val", "test")
DEFAULT_RATIOS = (0.8, 0.1, 0.1)
DEFAULT_SEED = 0


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
    if total <= 0:
        raise InputError(f"--split needs a positive weight, got {text!r}")
    return (values[0] / total, values[1] / total, values[2] / total)


def split_plants(
    plant_ids: Iterable[str],
    ratios: tuple[float, float, float] = DEFAULT_RATIOS,
    seed: int = DEFAULT_SEED,
) -> dict[str, list[str]]:
    """{"train": [...], "val": [...], "test": [...]}, each list sorted by id."""
    ids = sorted(set(plant_ids))
    order = sorted(ids, key=lambda i: hashlib.sha256(f"{seed}\0{i}".encode()).hexdigest())
    n = len(order)
    n_train = round(n * ratios[0])
    n_val = min(round(n * ratios[1]), n - n_train)
    cut = {"train": order[:n_train], "val": order[n_train : n_train + n_val]}
    cut["test"] = order[n_train + n_val :]
    return {split: sorted(cut[split]) for split in SPLITS}
