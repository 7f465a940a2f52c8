"""Several finished plants as one set of Gaussians: each plant read from its folder
(``plant.ply`` in its input frame, with ``run.json``'s export offset added back), stood on
the ground (its lowest 2% of Gaussians at z = 0) at its place, its centre (the median of its
Gaussians in x and y) there; instance ids made unique in the scene (plant k's ids follow
plant k - 1's largest), and each Gaussian's plant recorded. The rasterizer then renders the
scene in one pass, so plants occlude each other as they stand.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plantdreamer.errors import InputError
from plantdreamer.gaussians import Gaussians

GROUND_QUANTILE = 0.02  # a plant's lowest Gaussians below this share are strays, not its base
WIDTH_TRIM = 0.02  # share trimmed at each side when measuring a plant's width


@dataclass(frozen=True)
class ScenePlant:
    """A finished plant as a scene reads it: Gaussians in its input frame (float64 means)."""

    folder: Path
    gaussians: Gaussians
    means: np.ndarray  # float64 [N, 3], the input frame (plant.ply plus its export offset)
    class_names: dict[int, str]

    @property
    def width(self) -> float:
        """The plant's width on the ground: the longer side of its trimmed x-y box."""
        lo, hi = np.quantile(self.means[:, :2], [WIDTH_TRIM, 1 - WIDTH_TRIM], axis=0)
        return float((hi - lo).max())

    def footing(self) -> np.ndarray:
        """The point of the plant that stands on its place: its median x, y and its base z."""
        x, y = np.median(self.means[:, 0]), np.median(self.means[:, 1])
        return np.array([x, y, np.quantile(self.means[:, 2], GROUND_QUANTILE)])


def read_plant(folder: str | Path) -> ScenePlant:
    """A finished, labelled plant folder (``plant.ply`` with labels and its ``run.json``)."""
    from plantdreamer.exports.points import read_class_names
    from plantdreamer.io import read_splat_ply
    from plantdreamer.pipeline.rerender import GenerateFrame

    folder = Path(folder)
    ply = folder / "plant.ply"
    if not ply.is_file() or not (folder / "run.json").is_file():
        raise InputError(f"{folder} is not a finished plant folder (plant.ply and run.json)")
    g = read_splat_ply(ply)
    if g.labels is None:
        raise InputError(f"{ply} has no labels: a scene is made of labelled plants")
    frame = GenerateFrame.beside(ply)
    means = g.means.astype(np.float64)
    if frame is not None and frame.offset is not None:
        means = means + frame.offset
    finite = np.isfinite(means).all(axis=1)
    if not finite.any():
        raise InputError(f"{ply} has no Gaussian with finite coordinates")
    return ScenePlant(folder, g, means, read_class_names(ply))


@dataclass(frozen=True)
class ComposedScene:
    """The plants of a scene as one set of Gaussians (the input frame), with each
    Gaussian's plant (0..K-1) and instance ids unique in the scene."""

    gaussians: Gaussians
    means: np.ndarray  # float64 [N, 3]
    plant_of: np.ndarray  # int32 [N]
    class_names: dict[int, str]
    places: np.ndarray  # [K, 3]: where each plant's footing stands
    instance_offsets: list[int]  # plant k's instance i is i + instance_offsets[k]


def compose(plants: list[ScenePlant], places: np.ndarray) -> ComposedScene:
    """``plants`` standing at ``places`` ([K, 2] x, y on the ground)."""
    names: dict[int, str] = {}
    for plant in plants:
        for value, name in plant.class_names.items():
            if names.setdefault(value, name) != name:
                raise InputError(
                    f"{plant.folder}: class {value} is {name!r} there and {names[value]!r} in "
                    "another plant of the scene; a scene's plants must name their classes alike"
                )
    parts, means, plant_of, offsets = [], [], [], []
    next_instance = 0
    where = np.zeros((len(plants), 3))
    for k, (plant, (x, y)) in enumerate(zip(plants, places, strict=True)):
        where[k] = (x, y, 0.0)
        moved = plant.means - plant.footing() + where[k]
        labels = plant.gaussians.labels
        assert labels is not None
        labels = labels.copy()
        has = labels[:, 1] >= 0
        offsets.append(next_instance)
        labels[has, 1] += next_instance
        if has.any():
            next_instance = int(labels[has, 1].max()) + 1
        g = plant.gaussians
        parts.append(Gaussians(g.means, g.quats, g.log_scales, g.opacity_logits, g.sh, labels))
        means.append(moved)
        plant_of.append(np.full(len(g), k, dtype=np.int32))
    degree = max(p.sh_degree for p in parts)
    parts = [p.with_sh_degree(degree) for p in parts]
    all_means = np.concatenate(means)
    joined = Gaussians(
        all_means.astype(np.float32),
        np.concatenate([p.quats for p in parts]),
        np.concatenate([p.log_scales for p in parts]),
        np.concatenate([p.opacity_logits for p in parts]),
        np.concatenate([p.sh for p in parts]),
        np.concatenate([p.labels for p in parts if p.labels is not None]),
    )
    return ComposedScene(joined, all_means, np.concatenate(plant_of), names, where, offsets)
