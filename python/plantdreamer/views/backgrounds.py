"""What lies behind the exported views: the grey of the renders (the default), a colour, or
a folder of images (a user's bench, soil or greenhouse photos), one drawn per view from the
seed and composited with the render's alpha: out = C + (1 - alpha) x background, C being the
view rendered on black (alpha x the plant's colour). Only the picture changes: the labels,
instances and depth come from the Gaussians alone.

A folder is checked whole before anything runs (``check_folder``): every file in it (hidden
ones aside; sub-folders are not read) must be an image Pillow decodes, no larger than
``MAX_IMAGE_PIXELS``, the bound of every image the project reads. Each view scales its
image to cover the view (the smaller scale that fills both sides, bilinear), then crops it
at a drawn place.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from plantdreamer.errors import InputError
from plantdreamer.eval.images import MAX_IMAGE_PIXELS, check_image_size
from plantdreamer.settings import setting


@dataclass
class BackgroundConfig:
    """The background section: a colour or a folder of images behind the exported views."""

    background_colour: tuple[float, float, float] | None = setting(
        None,
        "A colour R G B in [0, 1] behind the exported views.",
        default_text="the grey of --background",
    )
    background_images: str | None = setting(
        None,
        "A folder of images (bench, soil, greenhouse photos) behind the exported views: one "
        "drawn per view from the seed, scaled to cover the view and cropped at a drawn place.",
    )

    def __post_init__(self) -> None:
        for f in fields(self):
            if isinstance(getattr(self, f.name), list):  # from JSON or TOML
                setattr(self, f.name, tuple(getattr(self, f.name)))

    @property
    def plain(self) -> bool:
        """The grey of the renders, as before."""
        return self.background_colour is None and self.background_images is None

    def validate(self) -> None:
        """A colour in range, one kind of background, and a folder of readable images."""
        colour = self.background_colour
        if colour is not None and not all(0.0 <= c <= 1.0 for c in colour):
            raise InputError(f"background-colour must be R G B in [0, 1], got {list(colour)}")
        if colour is not None and self.background_images is not None:
            raise InputError("give background-colour or background-images, not both")
        if self.background_images is not None:
            check_folder(self.background_images)


def check_folder(folder: str | Path) -> list[Path]:
    """The images of a background folder, sorted by name; one InputError naming the first
    file that is no image, too large or unreadable, or the folder when it holds none."""
    path = Path(folder)
    if not path.is_dir():
        raise InputError(f"background-images: {path} is not a folder")
    try:
        files = sorted(p for p in path.iterdir() if not p.name.startswith(".") and p.is_file())
    except OSError as exc:
        raise InputError(f"background-images: cannot list {path} ({exc})") from None
    if not files:
        raise InputError(f"background-images: {path} holds no image")
    for file in files:
        stat = file.stat()
        _check_image(file, stat.st_size, stat.st_mtime_ns)
    return files


@functools.lru_cache(maxsize=4096)
def _check_image(file: Path, size: int, mtime_ns: int) -> None:
    """Decodes ``file`` once per version of it (a spec checks every plant's settings)."""
    _decode(file)


def _decode(file: Path) -> np.ndarray:
    """RGB float32 [H, W, 3] in [0, 1]; the size checked from the header, before decoding."""
    from PIL import Image

    try:
        with Image.open(file) as image:
            check_image_size(*image.size, f"background-images: {file}")
            image.load()
            rgb = image.convert("RGB")
    except (OSError, Image.DecompressionBombError, ValueError, SyntaxError) as exc:
        raise InputError(
            f"background-images: {file} cannot be read as an image ({exc}); the folder may "
            f"hold only images of at most {MAX_IMAGE_PIXELS:,} pixels"
        ) from None
    return np.asarray(rgb, dtype=np.float32) / np.float32(255.0)


@functools.lru_cache(maxsize=16)
def _covering(file: Path, width: int, height: int) -> np.ndarray:
    """``file`` scaled (bilinear) to the smallest size that covers width x height."""
    from PIL import Image

    rgb = _decode(file)
    h, w = rgb.shape[:2]
    scale = max(width / w, height / h)
    size = (max(width, round(w * scale)), max(height, round(h * scale)))
    if size == (w, h):
        return rgb
    channels = [
        np.asarray(Image.fromarray(rgb[..., c]).resize(size, Image.Resampling.BILINEAR))
        for c in range(3)
    ]
    return np.stack(channels, axis=-1).astype(np.float32)


@dataclass(frozen=True)
class Background:
    """One view's background: an image [H, W, 3] and what was drawn (``record``)."""

    image: np.ndarray
    record: dict[str, Any]


def draw_background(
    config: BackgroundConfig, rng: np.random.Generator, width: int, height: int
) -> Background | None:
    """The background of one view (None: the grey of the render itself)."""
    if config.background_colour is not None:
        colour = np.asarray(config.background_colour, dtype=np.float32)
        image = np.broadcast_to(colour, (height, width, 3))
        return Background(image, {"colour": [float(c) for c in config.background_colour]})
    if config.background_images is None:
        return None
    files = check_folder(config.background_images)
    file = files[int(rng.integers(len(files)))]
    cover = _covering(file, width, height)
    x = int(rng.integers(cover.shape[1] - width + 1))
    y = int(rng.integers(cover.shape[0] - height + 1))
    image = cover[y : y + height, x : x + width]
    return Background(image, {"image": file.name, "crop": [x, y, width, height]})


def composite(on_black: np.ndarray, alpha: np.ndarray, background: np.ndarray) -> np.ndarray:
    """A render made on black, ``alpha`` [H, W], over ``background`` [H, W, 3]."""
    a = np.asarray(alpha, dtype=np.float32)[..., None]
    return np.asarray(on_black, dtype=np.float32) + (np.float32(1.0) - a) * background
