"""``PointCloud``: the in-memory form of a (plant) point cloud."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from plantdreamer.errors import InputError

# Most points plantdreamer samples or keeps for a run (about 2 GB of float64 working arrays);
# larger counts are refused before numpy allocates them.
MAX_POINTS = 20_000_000


def check_point_count(n: object, what: str = "number of points") -> int:
    """``n`` as an int in 1..MAX_POINTS, else InputError (floats and bools are refused)."""
    import numbers
    import operator

    if isinstance(n, bool) or not isinstance(n, numbers.Integral) or operator.index(n) < 1:
        raise InputError(f"{what} must be a positive integer, got {n!r}")
    count = operator.index(n)
    if count > MAX_POINTS:
        raise InputError(f"{what} {count:,} is above the limit of {MAX_POINTS:,}")
    return count


@dataclass
class PointCloud:
    """Points with optional colours, normals and extra per-point attributes.

    positions: float32 [N, 3] (float64 when read from a file that stores doubles).
    colors: float32 [N, 3] in [0, 1], or None.
    normals: float32 [N, 3], or None.
    attributes: extra per-point scalar arrays of length N, such as the L-System's organ
        ``label`` and leaf ``instance`` ids; PLY I/O keeps them as vertex properties.
    """

    positions: np.ndarray
    colors: np.ndarray | None = None
    normals: np.ndarray | None = None
    attributes: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.validate()

    def __len__(self) -> int:
        return int(self.positions.shape[0])

    def validate(self) -> None:
        """Raises InputError naming the first inconsistent field."""
        p = self.positions
        if not isinstance(p, np.ndarray) or p.ndim != 2 or p.shape[1] != 3:
            raise InputError(f"positions must be an [N, 3] array, got {_describe(p)}")
        n = p.shape[0]
        for name in ("colors", "normals"):
            value = getattr(self, name)
            if value is not None and (not isinstance(value, np.ndarray) or value.shape != (n, 3)):
                raise InputError(f"{name} must be an [{n}, 3] array, got {_describe(value)}")
        for name, value in self.attributes.items():
            if not isinstance(value, np.ndarray) or value.shape != (n,):
                raise InputError(
                    f"attribute {name!r} must be a [{n}] array, got {_describe(value)}"
                )

    def subset(self, index: np.ndarray) -> PointCloud:
        """The points selected by an index or boolean mask, with all their fields."""
        return PointCloud(
            positions=self.positions[index],
            colors=None if self.colors is None else self.colors[index],
            normals=None if self.normals is None else self.normals[index],
            attributes={k: v[index] for k, v in self.attributes.items()},
        )


def _describe(value: object) -> str:
    if isinstance(value, np.ndarray):
        return f"shape {list(value.shape)} of {value.dtype}"
    return type(value).__name__
