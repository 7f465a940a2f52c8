"""Makes docs/images/gallery.png, the README's contact sheet of a small dataset.

    python scripts/render_gallery.py

Generates six plants (bean, mint, kale; seeds 0 and 1; `--guidance none --steps 0
--resolution 192 --eval-views 4`) into `plants/<id>/` of a temporary folder, as
`plantdreamer dataset` lays them out (no Ray needed), then writes its label files and
gallery with `plantdreamer labels` and copies the gallery.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

OUT = Path(__file__).resolve().parent.parent / "docs" / "images" / "gallery.png"


def main() -> int:
    from plantdreamer.exports import LabelOptions, write_dataset_exports
    from plantdreamer.pipeline import GenerateConfig, generate_plants

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for species in ("bean", "mint", "kale"):
            for seed in (0, 1):
                cfg = GenerateConfig.of(
                    species=species, seed=seed, guidance="none", steps=0, resolution=192,
                    eval_views=4, turntable="none",
                )  # fmt: skip
                generate_plants(
                    [cfg], root / "plants" / f"{species}-s{seed:04d}", show_progress=False
                )
        # Six plants at 0.8/0.1/0.1: a split may draw none, which the picture does not mind.
        labels = write_dataset_exports(root, LabelOptions(allow_empty_split=True))
        OUT.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(labels.gallery, OUT)
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
