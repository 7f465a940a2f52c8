"""Makes docs/images/labelled_bean.png, the README's RGB | semantic | instance strip.

    python scripts/render_labelled_bean.py

Runs `plantdreamer generate --species bean --seed 1 --guidance none --eval-views 8` into a
temporary folder and puts view 1's render, class preview and instance map side by side
(instances in colours picked by a golden-ratio hue walk; black is background).
"""

from __future__ import annotations

import colorsys
import sys
import tempfile
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parent.parent / "docs" / "images" / "labelled_bean.png"


def instance_colours(n: int) -> np.ndarray:
    colours = [(0, 0, 0)]
    for i in range(n):
        r, g, b = colorsys.hsv_to_rgb((i * 0.618034) % 1.0, 0.75, 0.95)
        colours.append((int(255 * r), int(255 * g), int(255 * b)))
    return np.array(colours, dtype=np.uint8)


def main() -> int:
    import imageio.v3 as iio

    from plantdreamer.pipeline import GenerateConfig, generate_plants

    with tempfile.TemporaryDirectory() as tmp:
        cfg = GenerateConfig.of(species="bean", seed=1, guidance="none", eval_views=8)
        generate_plants([cfg], tmp, show_progress=False)
        out = Path(tmp)
        rgb = iio.imread(out / "renders" / "view_001.png")
        semantic = iio.imread(out / "labels" / "preview" / "view_001.png")[..., :3]
        instances = iio.imread(out / "instances" / "view_001.png")
        coloured = instance_colours(int(instances.max()))[instances]
    strip = np.concatenate([rgb, semantic, coloured], axis=1)
    iio.imwrite(OUT, strip)
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
