"""``Frame`` (one loaded ground-truth view) and ``FrameSource`` (where to load it from)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plantdreamer.cameras import Camera
from plantdreamer.errors import InputError
from plantdreamer.eval.images import read_mask, read_rgba

__all__ = ["Frame", "FrameSource"]


@dataclass
class Frame:
    """One ground-truth view.

    image: float32 [H, W, 3] in [0, 1], the stored colour (not composited).
    mask: bool [H, W], True on the plant, or None when the dataset has no mask.
    alpha: float32 [H, W] alpha channel of the image, or None (absent or opaque everywhere).
    """

    name: str
    camera: Camera
    image: np.ndarray
    mask: np.ndarray | None = None
    alpha: np.ndarray | None = None

    def ground_truth(self, background: tuple[float, float, float]) -> np.ndarray:
        """The image as a render with this background would show it: an RGBA image is
        composited over ``background``; an RGB image is returned as stored."""
        if self.alpha is None:
            return self.image
        a = self.alpha[..., None]
        bg = np.asarray(background, dtype=np.float32)
        return (self.image * a + bg * (1.0 - a)).astype(np.float32)


@dataclass(frozen=True)
class FrameSource:
    """A view whose pixels are read only by ``load()``, so that evaluating hundreds of
    full-resolution photos holds one of them in memory at a time.

    mask_path: a mask image (non-zero = plant); None means the image's alpha channel, if any.
    """

    name: str
    camera: Camera
    image_path: Path
    mask_path: Path | None = None

    def load(self) -> Frame:
        image, alpha = read_rgba(self.image_path)
        size = (self.camera.height, self.camera.width)
        if image.shape[:2] != size:
            raise InputError(
                f"{self.image_path} is {image.shape[1]}x{image.shape[0]} but its camera is "
                f"{size[1]}x{size[0]}"
            )
        mask = None
        if self.mask_path is not None:
            mask = read_mask(self.mask_path)
            if mask.shape != size:
                raise InputError(
                    f"mask {self.mask_path} is {mask.shape[1]}x{mask.shape[0]} but its image "
                    f"is {size[1]}x{size[0]}"
                )
        elif alpha is not None:
            mask = alpha != 0  # the authors' rule for masks: non-zero is plant
        return Frame(self.name, self.camera, image, mask, alpha)
