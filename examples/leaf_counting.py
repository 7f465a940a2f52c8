"""Make a small leaf-counting set with the Python API, then read its counts back: a kale at
two growth stages, seen from above, each view with the number of leaves it shows.

    python examples/leaf_counting.py [OUT]

Each plant folder holds its renders, ``counts.csv`` (one row per view: the visible leaves
and the plant's size in pixels, as leaf-counting sets give counts) and ``traits.json``
(the plant's exact traits: leaf count, leaf area, height, each leaf's size and angles).
The settings here run in seconds on a CPU with no weights; the comments give what a real
set uses (docs/traits.md).
"""

import csv
import json
import sys
from pathlib import Path

import plantdreamer

out = Path(sys.argv[1] if len(sys.argv) > 1 else "leaf-counting")

for stage in (0.5, 1.0):  # real: a series, e.g. 0.25, 0.5, 0.75, 1 of hundreds of seeds
    [plant] = plantdreamer.generate(
        out / f"kale-g{stage:g}",
        species="kale",
        seed=0,
        growth=stage,  # the plant earlier in its development; leaf ids persist
        guidance="none",  # real: "sds" with the weights and a kale LoRA
        points=3000,  # real: 100_000
        resolution=96,  # real: 512 or more
        eval_views=2,  # real: 60 or 120 views around the plant
        eval_elevation_deg=70.0,  # from above, as leaf-counting images are taken
        turntable="none",
        quiet=True,
    )
    traits = json.loads(plant.traits.read_text())["plant"]
    with open(plant.counts, newline="") as f:
        views = list(csv.DictReader(f))
    seen = ", ".join(f"{v['file_name']}: {v['leaf_count']}" for v in views)
    print(
        f"{plant.folder.name}: {traits['leaf_count']} leaves, "
        f"{traits['leaf_area'] * 1e4:.0f} cm2 of leaf, {traits['height'] * 100:.1f} cm tall; "
        f"leaves visible per view: {seen}"
    )
