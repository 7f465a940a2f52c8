"""Measures the table of docs/labels.md, "Specks and framing": how many 8-connected pieces
the objects of generated plants' label maps have, how many of them are specks, and how many
objects touch the image border, per species.

    .venv/bin/python scripts/label_quality.py [--points 30000] [--resolution 320] [--views 8]

Each plant is generated as initialised (`--guidance none --steps 0`, seed 0) at the
default evaluation orbit. An object is a leaf instance of a view (the instance map), or a
class region of a view (the class map: stem, pot, soil; and each leaf); a speck is a piece under 16
px beside the object's largest piece. The class map's leaf pixels are told apart by their
instance (a leaf is an object of its own, not the whole leaf class). Self-contained (no import of the speck rule), so it
measures any version of the package.
"""

from __future__ import annotations

import argparse
import tempfile
from collections import deque
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from plantdreamer.pipeline import GenerateConfig, generate_plants

SPECIES = ("bean", "mint", "kale")
SPECK = 16  # pixels: the speck size measured (label_pieces.MIN_PIECE)
STEPS = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)]


def piece_sizes(mask: np.ndarray) -> list[int]:
    """Sizes of the 8-connected pieces of a bool mask (breadth-first, largest first)."""
    h, w = mask.shape
    seen = ~mask
    sizes = []
    for y, x in zip(*np.nonzero(mask), strict=True):
        if seen[y, x]:
            continue
        seen[y, x] = True
        queue, size = deque([(y, x)]), 0
        while queue:
            cy, cx = queue.popleft()
            size += 1
            for dy, dx in STEPS:
                ny, nx = cy + dy, cx + dx
                if 0 <= ny < h and 0 <= nx < w and not seen[ny, nx]:
                    seen[ny, nx] = True
                    queue.append((ny, nx))
        sizes.append(size)
    return sorted(sizes, reverse=True)


def measure(folder: Path, maps: str) -> dict[str, float]:
    """Piece counts of the objects of every view: the instance map's leaves ("instances"),
    or the class map's classes, leaf pixels told apart by their instance ("labels")."""
    objects = pieces = multi = specks = singles = border = 0
    most = 0
    for path in sorted((folder / "instances").glob("view_*.png")):
        image = iio.imread(path).astype(np.int64)
        if maps == "labels":
            label = iio.imread(folder / "labels" / path.name).astype(np.int64)
            image = np.where(label == 0, 0, label * 65536 + image)
        for value in np.unique(image):
            if value == 0:
                continue
            mask = image == value
            sizes = piece_sizes(mask)
            objects += 1
            pieces += len(sizes)
            multi += len(sizes) > 1
            most = max(most, len(sizes))
            specks += sum(s < SPECK for s in sizes[1:])
            singles += sum(s == 1 for s in sizes[1:])
            border += bool(mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())
    return {
        "objects": objects,
        "pieces per object": pieces / max(objects, 1),
        "most pieces": most,
        "objects in pieces": multi,
        "specks": specks,
        "single pixels": singles,
        "touching the border": border,
    }


def border_views(folder: Path) -> tuple[int, int, float]:
    """Views whose plant touches the border, views, and the plant's mean share of the frame."""
    touching, shares = 0, []
    paths = sorted((folder / "labels").glob("view_*.png"))
    for path in paths:
        label = iio.imread(path) > 0
        touching += bool(
            label[0].any() or label[-1].any() or label[:, 0].any() or label[:, -1].any()
        )
        shares.append(label.mean())
    return touching, len(paths), float(np.mean(shares))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--points", type=int, default=30_000)
    parser.add_argument("--resolution", type=int, default=320)
    parser.add_argument("--views", type=int, default=8)
    args = parser.parse_args()
    print(
        "| species | map | objects | pieces per object | most | objects in pieces | specks "
        "| single px | objects on border | views on border | plant share |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for species in SPECIES:
        cfg = GenerateConfig.of(
            species=species, seed=0, points=args.points, resolution=args.resolution,
            eval_views=args.views, turntable="none", steps=0, guidance="none",
        )  # fmt: skip
        with tempfile.TemporaryDirectory() as tmp:
            generate_plants([cfg], tmp, show_progress=False)
            touching, views, share = border_views(Path(tmp))
            for maps in ("instances", "labels"):
                m = measure(Path(tmp), maps)
                print(
                    f"| {species} | {maps} | {m['objects']} | {m['pieces per object']:.2f} "
                    f"| {m['most pieces']} | {m['objects in pieces']} | {m['specks']} "
                    f"| {m['single pixels']} | {m['touching the border']} "
                    f"| {touching} / {views} | {share:.1%} |"
                )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
