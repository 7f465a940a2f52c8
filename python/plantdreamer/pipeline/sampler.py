"""Random training cameras on an orbit, from a seeded generator whose state checkpoints."""

from __future__ import annotations

from typing import Any

import numpy as np

from plantdreamer.cameras import Camera, orbit
from plantdreamer.pipeline.config import CameraRanges


class CameraSampler:
    def __init__(self, ranges: CameraRanges, resolution: int, seed: int) -> None:
        self.ranges = ranges
        self.resolution = resolution
        self.rng = np.random.default_rng([seed, 0xCA3E5])

    def sample(self) -> Camera:
        r = self.ranges
        distance, elevation, azimuth, fovy = (
            self.rng.uniform(*rng)
            for rng in (r.distance, r.elevation_deg, r.azimuth_deg, r.fovy_deg)
        )
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
