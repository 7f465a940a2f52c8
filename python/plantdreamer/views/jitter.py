"""Appearance jitter of the exported views, off by default: per view a white balance (a gain
per channel), a brightness (one gain) and a contrast (about mid-grey, 0.5), each drawn
uniformly in [1 - J, 1 + J] from the seed and applied in that order to the finished picture
(background included, as a camera's exposure is), then clipped to [0, 1]. The values drawn
are written beside the view (transforms.json, ``jitter``), never baked in silently; the
labels, instances and depth are not touched.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from plantdreamer.settings import setting

JITTER = (0.0, 1.0)  # a jitter J draws factors in [1 - J, 1 + J]


@dataclass
class JitterConfig:
    """The jitter section: how far each view's appearance may be moved (0: not at all)."""

    jitter_brightness: float = setting(
        0.0, "Brightness jitter J of each exported view: a gain in [1 - J, 1 + J].", range=JITTER
    )
    jitter_contrast: float = setting(
        0.0,
        "Contrast jitter J of each exported view: a factor in [1 - J, 1 + J] about mid-grey.",
        range=JITTER,
    )
    jitter_white_balance: float = setting(
        0.0,
        "White-balance jitter J of each exported view: a gain per channel in [1 - J, 1 + J].",
        range=JITTER,
    )

    @property
    def off(self) -> bool:
        return self.jitter_brightness == self.jitter_contrast == self.jitter_white_balance == 0


@dataclass(frozen=True)
class Jitter:
    """One view's jitter: per-channel gains, a brightness gain and a contrast factor."""

    white_balance: tuple[float, float, float]
    brightness: float
    contrast: float

    def record(self) -> dict[str, Any]:
        return {
            "white_balance": list(self.white_balance),
            "brightness": self.brightness,
            "contrast": self.contrast,
        }

    def apply(self, image: np.ndarray) -> np.ndarray:
        """The jittered picture (float [H, W, 3] in [0, 1])."""
        gains = np.asarray(self.white_balance, dtype=np.float32) * np.float32(self.brightness)
        out = np.asarray(image, dtype=np.float32) * gains
        out = np.float32(0.5) + np.float32(self.contrast) * (out - np.float32(0.5))
        return np.clip(out, 0.0, 1.0)


def draw_jitter(config: JitterConfig, rng: np.random.Generator) -> Jitter | None:
    """One view's jitter (None when the jitter is off)."""
    if config.off:
        return None

    def factor(j: float, n: int | None = None) -> Any:
        return rng.uniform(1.0 - j, 1.0 + j, n)

    gains = factor(config.jitter_white_balance, 3)
    return Jitter(
        (float(gains[0]), float(gains[1]), float(gains[2])),
        float(factor(config.jitter_brightness)),
        float(factor(config.jitter_contrast)),
    )
