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
  naming the problem (a corrupt photo is better fixed than silently skipped), and so are a
  photo over ``MAX_PHOTO_PIXELS`` (checked from its header, before its pixels are decoded),
  one whose resized copy would be longer than ``MAX_ASPECT`` times the resolution (a
  20000 x 1 strip would become 10,240,000 x 512 at 512), a caption that is not UTF-8 and a
  template with a field other than ``{species}``.
"""

from __future__ import annotations

import string
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from plantdreamer.errors import InputError
from plantdreamer.guidance.config import DEFAULT_PROMPT_TEMPLATE

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".webp", ".bmp", ".tif", ".tiff")
DEFAULT_CAPTION = DEFAULT_PROMPT_TEMPLATE
MAX_PHOTO_PIXELS = 8192 * 8192  # a photo's decoded size (Pillow refuses only beyond 2 x 89 M)
MAX_ASPECT = 4  # longest side / shortest side after the resize: what a crop can still use


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


def resized_size(size: tuple[int, int], resolution: int) -> tuple[int, int]:
    """(width, height) of a photo of ``size`` with its shorter side at ``resolution``."""
    w, h = size
    scale = resolution / min(w, h)
    return max(resolution, round(w * scale)), max(resolution, round(h * scale))


def check_photo_size(path: Path, size: tuple[int, int], resolution: int) -> None:
    """Refuses a photo too large to decode or whose resized copy is an unusable strip."""
    w, h = size
    if w * h > MAX_PHOTO_PIXELS:
        raise InputError(
            f"photo {str(path)!r} is {w} x {h} pixels, over the limit of {MAX_PHOTO_PIXELS:,}: "
            "scale it down"
        )
    new = resized_size(size, resolution)
    if max(new) > MAX_ASPECT * resolution:
        raise InputError(
            f"photo {str(path)!r} is {w} x {h} pixels: at resolution {resolution} it would "
            f"become {new[0]} x {new[1]}, longer than {MAX_ASPECT} x {resolution}; crop it"
        )


def resize_short_side(image, size: int):  # type: ignore[no-untyped-def]
    from PIL import Image

    new = resized_size(image.size, size)
    return image if new == image.size else image.resize(new, Image.Resampling.LANCZOS)


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


@dataclass(frozen=True)
class PhotoSize:
    """A photo's size and the size training resizes it to (from its header alone)."""

    path: Path
    size: tuple[int, int]
    resized: tuple[int, int]


def photo_sizes(folder: str | Path, resolution: int) -> list[PhotoSize]:
    """Every photo's size and resized size, each checked (``check_photo_size``) from its
    header before any pixel is decoded: ``lora train --dry-run``'s preview, and its
    refusals before any model loads."""
    from PIL import Image, UnidentifiedImageError

    sizes = []
    for path in list_images(Path(folder)):
        try:
            with Image.open(path) as opened:
                size = opened.size
        except (UnidentifiedImageError, OSError, ValueError, Image.DecompressionBombError) as exc:
            raise InputError(f"cannot read image {str(path)!r}: {exc}") from exc
        check_photo_size(path, size, resolution)
        sizes.append(PhotoSize(path, size, resized_size(size, resolution)))
    return sizes


def caption_for(path: Path, species: str, template: str) -> str:
    text_file = path.with_suffix(".txt")
    if text_file.is_file():
        try:
            caption = text_file.read_bytes().decode("utf-8").strip()
        except UnicodeDecodeError as exc:
            raise InputError(f"caption {str(text_file)!r} is not UTF-8 text ({exc})") from None
        if caption:
            return caption
    return template.format(species=species)


def check_caption_template(template: str) -> None:
    """A template is text with ``{species}``, its only field (``{{`` and ``}}`` are braces),
    that formats a species name: a format spec or conversion a name cannot take
    (``{species:d}``, ``{species!z}``) is refused here, not when the captions are made."""
    try:
        fields = {f for _, f, _, _ in string.Formatter().parse(template) if f is not None}
    except ValueError as exc:
        raise InputError(f"caption template {template!r} is not a template ({exc})") from None
    if fields != {"species"}:
        other = sorted(fields - {"species"})
        raise InputError(
            f"caption template must contain '{{species}}' and no other field, got {template!r}"
            + (f" (with {', '.join('{' + f + '}' for f in other)})" if other else "")
        )
    try:
        template.format(species="bean")
    except (ValueError, KeyError, IndexError, AttributeError, TypeError) as exc:
        raise InputError(
            f"caption template {template!r} cannot format a species name ({exc}); write "
            "'{species}' with no format spec or conversion"
        ) from None


def load_examples(
    folder: str | Path, species: str, resolution: int, template: str = DEFAULT_CAPTION
) -> list[Example]:
    """Every photo of ``folder``, decoded, converted to RGB and resized."""
    from PIL import Image, UnidentifiedImageError

    if resolution < 8:
        raise InputError(f"resolution must be >= 8 px, got {resolution}")
    check_caption_template(template)
    examples = []
    for path in list_images(Path(folder)):
        try:
            with Image.open(path) as opened:
                check_photo_size(path, opened.size, resolution)
                opened.load()
                mode, size = opened.mode, opened.size
                rgb = to_rgb(opened)
        except (UnidentifiedImageError, OSError, ValueError, Image.DecompressionBombError) as exc:
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
