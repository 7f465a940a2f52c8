"""Random training cameras on an orbit, from a seeded generator whose state checkpoints."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from plantdreamer.cameras import Camera, orbit
from plantdreamer.pipeline.settings.train_config import CameraRanges

ElevationDraw = Callable[[np.random.Generator, float, float], float]


def area_uniform_elevation(rng: np.random.Generator, low: float, high: float) -> float:
    """Elevation (degrees) uniform on the sphere's area between ``low`` and ``high``:
    asin of a uniform draw between sin(low) and sin(high), density proportional to
    cos(elevation). threestudio's mapping since 2023-11-27 (``data/uncond.py:156-172``), the
    one PlantDreamer's threestudio runs."""
    s = rng.uniform(math.sin(math.radians(low)), math.sin(math.radians(high)))
    return math.degrees(math.asin(s))


def legacy_area_uniform_elevation(rng: np.random.Generator, low: float, high: float) -> float:
    """threestudio's area-uniform elevation before 2023-11-27: asin(2p - 1) with p uniform
    between (low + 90)/180 and (high + 90)/180. The range maps through p, so (-10, 80)
    gives about (-6.4, 62.7): the top of the range is never reached."""
    p = rng.uniform((low + 90.0) / 180.0, (high + 90.0) / 180.0)
    return math.degrees(math.asin(2.0 * p - 1.0))


def mixed_elevation(
    rng: np.random.Generator, low: float, high: float, area: ElevationDraw | None = None
) -> float:
    """threestudio's training elevation: uniform in degrees or ``area`` (default: the
    full-range area-uniform draw), 50/50."""
    if rng.random() < 0.5:
        return float(rng.uniform(low, high))
    return (area or area_uniform_elevation)(rng, low, high)


# ``GenerateConfig.elevation_sampling`` choices other than "uniform": their area-uniform half.
_AREA_DRAWS: dict[str, ElevationDraw] = {
    "mixed": legacy_area_uniform_elevation,
    "mixed-full": area_uniform_elevation,
}


class CameraSampler:
    def __init__(
        self, ranges: CameraRanges, resolution: int, seed: int, elevation: str = "uniform"
    ) -> None:
        self.ranges = ranges
        self.resolution = resolution
        self.elevation = elevation
        self.rng = np.random.default_rng([seed, 0xCA3E5])

    def sample(self) -> Camera:
        r, rng = self.ranges, self.rng
        distance = rng.uniform(*r.distance)
        if self.elevation in _AREA_DRAWS:
            elevation = mixed_elevation(rng, *r.elevation_deg, _AREA_DRAWS[self.elevation])
        else:
            elevation = rng.uniform(*r.elevation_deg)
        azimuth = rng.uniform(*r.azimuth_deg)
        fovy = rng.uniform(*r.fovy_deg)
        return orbit(distance, elevation, azimuth, fovy, self.resolution, self.resolution)

    def peek(self) -> Camera:
        """The camera the next ``sample()`` returns, without drawing it."""
        state = self.rng.bit_generator.state
        camera = self.sample()
        self.rng.bit_generator.state = state
        return camera

    def state(self) -> dict[str, Any]:
        return dict(self.rng.bit_generator.state)

    def set_state(self, state: dict[str, Any]) -> None:
        self.rng.bit_generator.state = state
