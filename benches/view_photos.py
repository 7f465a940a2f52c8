"""Background photos for the benches of the exported views, from scikit-image's sample
images (no download): textures tinted as a bench, soil or greenhouse would be, and colour
photos. ``TRAINING`` and ``HELD_OUT`` share no image, so a bench can score on backgrounds
its training never saw."""

from __future__ import annotations

from pathlib import Path

import numpy as np

# name -> (scikit-image sample, tint of a grey texture: None for a colour photo)
TRAINING = {
    "grass": ("grass", (0.45, 0.75, 0.35)),
    "brick": ("brick", (0.85, 0.5, 0.4)),
    "coffee": ("coffee", None),
    "rocket": ("rocket", None),
}
HELD_OUT = {
    "gravel": ("gravel", (0.75, 0.62, 0.48)),
    "camera": ("camera", (0.9, 0.9, 0.85)),
    "chelsea": ("chelsea", None),
}


def write_photos(folder: Path, which: dict[str, tuple[str, tuple | None]]) -> Path:
    """Writes the photos ``which`` names into ``folder`` as PNGs; returns the folder."""
    import skimage.data
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    for name, (sample, tint) in which.items():
        image = np.asarray(getattr(skimage.data, sample)(), dtype=np.float32)
        if image.ndim == 2:
            image = image[..., None] * np.asarray(tint, np.float32)
        Image.fromarray(np.clip(image, 0, 255).astype(np.uint8)).save(folder / f"{name}.png")
    return folder
