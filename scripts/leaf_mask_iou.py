"""Measures the table of docs/labels.md, "How well the masks match the plant": the leaf-mask
IoU of L-System plants generated as initialised (`--guidance none`, no steps), for both
initial shapes, against a z-buffer of the mesh's leaf faces (`tests/leaf_masks.py`).

    .venv/bin/python scripts/leaf_mask_iou.py [--views 8] [--out docs/leaf_mask_iou.md]

Each row: min-max over the views of the evaluation orbit, 100k points. The last column is
the bound one pixel sets: the exact mesh mask against itself grown by one pixel (3 x 3).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from leaf_masks import leaf_mask_ious  # noqa: E402
from plantdreamer.atomic import write_text  # noqa: E402
from plantdreamer.pipeline import GenerateConfig, generate_plants  # noqa: E402

ROWS = [("bean", 0, 512), ("bean", 2, 512), ("mint", 0, 512)]
ROWS += [("bean", 0, 1024), ("bean", 1, 1024), ("bean", 2, 1024)]
SHAPES = ("sphere", "surface")


def ious(
    species: str, seed: int, size: int, shape: str, views: int
) -> tuple[list[float], list[float]]:
    """Leaf-mask IoU per view, and (once per row) that of the mesh mask grown by one pixel."""
    cfg = GenerateConfig.of(
        species=species, seed=seed, points=100_000, resolution=size, eval_views=views,
        turntable_frames=2, steps=0, guidance="none", init_shape=shape,
    )  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        generate_plants([cfg], tmp, show_progress=False)
        out = Path(tmp)
        bound = leaf_mask_ious(out, species, seed, True) if shape == SHAPES[-1] else []
        return leaf_mask_ious(out, species, seed), bound


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--views", type=int, default=8)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "leaf_mask_iou.md")
    args = parser.parse_args()
    lines = [
        "# Leaf-mask IoU against the mesh\n",
        f"Made by `python scripts/leaf_mask_iou.py --views {args.views}` (see its docstring).\n",
        "| plant, seed, image size | `sphere` (the released init) | `surface` (default) "
        "| mesh mask grown by one pixel |",
        "|---|---|---|---|",
    ]
    for species, seed, size in ROWS:
        cells = []
        for shape in SHAPES:
            v, bound = ious(species, seed, size, shape, args.views)
            cells.append(f"{min(v):.2f}-{max(v):.2f}")
            print(species, seed, size, shape, [round(x, 3) for x in v], flush=True)
        cells.append(f"{min(bound):.2f}-{max(bound):.2f}")
        lines.append(f"| {species} {seed}, {size} px | {' | '.join(cells)} |")
    write_text(args.out, "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
