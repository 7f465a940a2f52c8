"""Where a scene's plants stand on the ground plane (z up): a grid, or seeded places at
least the spacing apart, both centred on the origin."""

from __future__ import annotations

import math

import numpy as np

from plantdreamer.errors import InputError

TRIES = 2000  # darts per plant before the random layout's square grows


def tray_positions(count: int, layout: str, spacing: float, rng: np.random.Generator) -> np.ndarray:
    """[count, 2] x, y of each plant: ``grid`` fills rows of ceil(sqrt(count)) columns,
    ``spacing`` apart; ``random`` throws darts into a square of side
    ``spacing * (sqrt(count) + 1)``, keeping each at least ``spacing`` from the others (the
    square grows by 10% whenever a plant finds no place in ``TRIES`` darts)."""
    if count < 1:
        raise InputError(f"a scene needs at least one plant, got {count}")
    if layout == "grid":
        columns = math.ceil(math.sqrt(count))
        rows = math.ceil(count / columns)
        index = np.arange(count)
        xy = np.stack([index % columns, index // columns], axis=1).astype(np.float64)
        xy -= [(columns - 1) / 2, (rows - 1) / 2]
        return xy * spacing
    if layout != "random":
        raise InputError(f"scene-layout must be grid or random, got {layout!r}")
    side = spacing * (math.sqrt(count) + 1)
    placed: list[np.ndarray] = []
    while len(placed) < count:
        for _ in range(TRIES):
            p = rng.uniform(-side / 2, side / 2, 2)
            if all(np.hypot(*(p - q)) >= spacing for q in placed):
                placed.append(p)
                break
        else:
            side *= 1.1
    xy = np.stack(placed)
    return xy - (xy.min(axis=0) + xy.max(axis=0)) / 2
