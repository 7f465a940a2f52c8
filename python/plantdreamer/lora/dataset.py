"""The species photo set for LoRA training: images, captions, light augmentation.

A folder of photos (png, jpg, jpeg, webp, bmp, tif, tiff) of one species against a plain
background, about 30 in the paper. Each image may have a caption in ``<name>.txt`` beside
it; otherwise the template is used (default: the generation prompt template,
"a {species} plant in a pot", so generation prompts a LoRA with the words it learnt).

- Images of any size are accepted: each is resized so its shorter side is ``resolution``
  (Lanczos), then training crops a random ``resolution`` square from it.
- Non-RGB images are converted: greyscale and palette images to RGB, images with
  transparency composited over a white background (a plain background, as photographed).
- An empty folder, a missing folder or a file that cannot be decoded is an ``InputError``
  naming the problem (a corrupt photo is better fixed than silently skipped).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from plantdreamer.errors import InputError
from plantdreamer.guidance.config import DEFAULT_PROMPT_TEMPLATE

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".webp", ".bmp", ".tif", ".tiff")
DEFAULT_CAPTION = DEFAULT_PROMPT_TEMPLATE


@dataclass
class Example:
    """One photo, shorter side resized to the training resolution, as float32 [3, H, W] in [0, 1]."""

    path: Path
    image: torch.Tensor
    caption: str
    original_size: tuple[int, int]
    original_mode: str


def to_rgb(image):  # type: ignore[no-untyped-def]
    """A PIL image as RGB; transparency is composited over white."""
    from PIL import Image

    if image.mode == "RGB":
        return image
    if image.mode in ("RGBA", "LA", "PA") or (image.mode == "P" and "transparency" in image.info):
        rgba = image.convert("RGBA")
        background = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
        return Image.alpha_composite(background, rgba).convert("RGB")
    if image.mode in ("I;16", "I", "F"):  # 16-bit / float greyscale: rescale to 8 bits
        array = np.asarray(image, dtype=np.float64)
        lo, hi = float(array.min()), float(array.max())
        scaled = (array - lo) / (hi - lo) * 255.0 if hi > lo else np.zeros_like(array)
        return Image.fromarray(scaled.astype(np.uint8)).convert("RGB")
    return image.convert("RGB")


def resize_short_side(image, size: int):  # type: ignore[no-untyped-def]
    from PIL import Image

    w, h = image.size
    scale = size / min(w, h)
    new = (max(size, round(w * scale)), max(size, round(h * scale)))
    return image if new == (w, h) else image.resize(new, Image.Resampling.LANCZOS)


def list_images(folder: Path) -> list[Path]:
    if not folder.exists():
        raise InputError(f"image folder {str(folder)!r} does not exist")
    if not folder.is_dir():
        raise InputError(f"{str(folder)!r} is not a folder of images")
    try:
        files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    except PermissionError as exc:
        raise InputError(f"cannot read image folder {str(folder)!r}: {exc}") from exc
    if not files:
        raise InputError(
            f"no images in {str(folder)!r} (looked for {', '.join(IMAGE_SUFFIXES)}); "
            "put about 30 photos of the species there"
        )
    return files


def caption_for(path: Path, species: str, template: str) -> str:
    text_file = path.with_suffix(".txt")
    if text_file.is_file():
        caption = text_file.read_text(encoding="utf-8").strip()
        if caption:
            return caption
    return template.format(species=species)


def load_examples(
    folder: str | Path, species: str, resolution: int, template: str = DEFAULT_CAPTION
) -> list[Example]:
    """Every photo of ``folder``, decoded, converted to RGB and resized."""
    from PIL import Image, UnidentifiedImageError

    if resolution < 8:
        raise InputError(f"resolution must be >= 8 px, got {resolution}")
    if "{species}" not in template:
        raise InputError(f"caption template must contain '{{species}}', got {template!r}")
    examples = []
    for path in list_images(Path(folder)):
        try:
            with Image.open(path) as opened:
                opened.load()
                mode, size = opened.mode, opened.size
                rgb = to_rgb(opened)
        except (UnidentifiedImageError, OSError, ValueError) as exc:
            raise InputError(f"cannot read image {str(path)!r}: {exc}") from exc
        rgb = resize_short_side(rgb, resolution)
        array = np.asarray(rgb, dtype=np.float32) / 255.0
        tensor = torch.from_numpy(array.copy()).permute(2, 0, 1).contiguous()
        examples.append(Example(path, tensor, caption_for(path, species, template), size, mode))
    return examples


def augment(image: torch.Tensor, resolution: int, generator: torch.Generator) -> torch.Tensor:
    """Random ``resolution`` square crop and random horizontal flip (seeded)."""
    _, h, w = image.shape
    top = int(torch.randint(0, h - resolution + 1, (1,), generator=generator))
    left = int(torch.randint(0, w - resolution + 1, (1,), generator=generator))
    crop = image[:, top : top + resolution, left : left + resolution]
    if bool(torch.rand((), generator=generator) < 0.5):
        crop = crop.flip(-1)
    return crop
