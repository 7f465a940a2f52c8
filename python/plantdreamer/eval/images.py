"""Reading ground-truth images and masks as float arrays."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from plantdreamer.errors import InputError

# Tried in this order when a transforms.json ``file_path`` has no extension.
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".JPEG", ".webp", ".tif", ".tiff")


def resolve_image_path(path: Path) -> Path:
    """``path`` itself if it exists, else ``path`` + the first known extension that exists."""
    if path.is_file():
        return path
    for ext in IMAGE_EXTENSIONS:
        candidate = path.with_name(path.name + ext)
        if candidate.is_file():
            return candidate
    raise FileNotFoundError(
        f"image not found: {path} (also tried the extensions {', '.join(IMAGE_EXTENSIONS[:3])}, ...)"
    )


def read_rgba(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """RGB float32 [H, W, 3] in [0, 1] and the alpha channel float32 [H, W], or None.

    8-bit images are divided by 255 (the authors' convention), 16-bit ones by 65535. An alpha
    channel that is opaque everywhere carries no mask and is returned as None.
    """
    from PIL import Image

    try:
        with Image.open(path) as opened:
            check_image_size(*opened.size, path)  # before the pixels are decoded
            opened.load()
            im: Image.Image = opened
            mode = im.mode
            if mode == "P":
                im = im.convert("RGBA" if "transparency" in im.info else "RGB")
            elif mode in ("I;16", "I;16B", "I;16L", "I"):
                gray = np.asarray(im, dtype=np.float64) / 65535.0
                rgb = np.repeat(np.clip(gray, 0.0, 1.0)[..., None], 3, axis=2)
                return rgb.astype(np.float32), None
            elif mode not in ("RGB", "RGBA"):
                im = im.convert("RGBA" if "A" in mode else "RGB")
            data = np.asarray(im, dtype=np.float32) / 255.0
    except (OSError, Image.DecompressionBombError) as exc:
        if isinstance(exc, FileNotFoundError):
            raise
        raise InputError(f"cannot read image {path}: {exc}") from exc
    rgb = np.ascontiguousarray(data[..., :3])
    alpha = np.ascontiguousarray(data[..., 3]) if data.shape[2] == 4 else None
    if alpha is not None and bool((alpha >= 1.0).all()):
        alpha = None
    return rgb, alpha


def read_mask(path: Path) -> np.ndarray:
    """Boolean [H, W]: True where the grayscale value of the mask image is non-zero."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            check_image_size(*im.size, path)
            gray = np.asarray(im.convert("L") if im.mode not in ("L", "1", "I;16", "I") else im)
    except (OSError, Image.DecompressionBombError) as exc:
        if isinstance(exc, FileNotFoundError):
            raise
        raise InputError(f"cannot read mask {path}: {exc}") from exc
    return np.asarray(gray) != 0


# Largest image read or rendered for evaluation: 8192 x 8192. A header claiming more is refused
# before any pixel buffer is allocated.
MAX_IMAGE_PIXELS = 8192 * 8192


def check_image_size(width: int, height: int, where: object) -> tuple[int, int]:
    """``(width, height)`` if positive and within MAX_IMAGE_PIXELS, else InputError."""
    if not (width > 0 and height > 0):
        raise InputError(f"{where}: image size must be positive, got {width}x{height}")
    if width * height > MAX_IMAGE_PIXELS:
        raise InputError(
            f"{where}: {width} x {height} pixels is above the limit of {MAX_IMAGE_PIXELS:,} "
            f"pixels (one float RGBA copy alone needs {width * height * 16 / 2**30:.1f} GiB)"
        )
    return width, height


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) from the file header, without decoding the pixels."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            return check_image_size(int(im.size[0]), int(im.size[1]), path)
    except (OSError, Image.DecompressionBombError) as exc:
        if isinstance(exc, FileNotFoundError):
            raise
        raise InputError(f"cannot read image {path}: {exc}") from exc
