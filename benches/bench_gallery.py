"""`plantdreamer gallery` of a large dataset: wall time, peak memory and the sheet's size.

A dataset of N finished plants is laid out as `dataset` leaves it (DIR/plants/<id>/ with
run.json, transforms.json of 120 views, a 512 px render and its label preview per plant;
the files of one plant are hard-linked into the others, so setting up 10,000 plants takes
seconds and no disk). Each size runs `plantdreamer gallery` in a fresh process (the wall
time includes its start-up and imports); peak memory is that process's maximum resident
set size.

    python benches/bench_gallery.py [--plants 1000,10000]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parent))
from host import host_line

RESULTS = Path(__file__).resolve().parent / "results"
VIEWS = 120
SIDE = 512


def template(folder: Path) -> dict[str, Path]:
    """One plant's files: a render-like picture (a green disc on grey), its preview, a
    run.json of a real config and a transforms.json of VIEWS frames."""
    from plantdreamer.pipeline import GenerateConfig

    y, x = np.mgrid[:SIDE, :SIDE]
    disc = (x - SIDE / 2) ** 2 + (y - SIDE / 2) ** 2 < (SIDE / 3) ** 2
    render = np.full((SIDE, SIDE, 3), 191, np.uint8)
    render[disc] = (40, 160, 50)
    render[..., 1] = np.where(disc, 140 + x % 60, render[..., 1])
    preview = np.zeros_like(render)
    preview[disc] = (0, 200, 0)
    (folder / "renders").mkdir(parents=True)
    (folder / "labels" / "preview").mkdir(parents=True)
    Image.fromarray(render).save(folder / "renders" / "view_000.png")
    Image.fromarray(preview).save(folder / "labels" / "preview" / "view_000.png")
    frames = [
        {"file_path": f"renders/view_{i:03d}.png", "transform_matrix": np.eye(4).tolist(),
         "depth_file_path": f"depth/view_{i:03d}.png", "mask_path": f"labels/view_{i:03d}.png"}
        for i in range(VIEWS)
    ]  # fmt: skip
    (folder / "transforms.json").write_text(json.dumps({"fl_x": 500.0, "frames": frames}))
    config = GenerateConfig.of(species="bean").to_dict()
    (folder / "run.json").write_text(json.dumps({"config": config}))
    return {
        name: folder / name
        for name in ("renders/view_000.png", "labels/preview/view_000.png", "transforms.json")
    }


def make_dataset(root: Path, plants: int, files: dict[str, Path]) -> None:
    run_json = json.loads((files["transforms.json"].parent / "run.json").read_text())
    for i in range(plants):
        folder = root / "plants" / f"bean-s{i:05d}"
        (folder / "labels" / "preview").mkdir(parents=True)
        (folder / "renders").mkdir()
        for name, source in files.items():
            os.link(source, folder / name)
        run_json["config"]["seed"] = i
        (folder / "run.json").write_text(json.dumps(run_json))


CHILD = """
import resource, sys
from plantdreamer.cli import main
try:
    main(["gallery", sys.argv[1], "--out", sys.argv[2], "--overwrite"])
except SystemExit as exit:
    assert not exit.code, exit.code
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def measure(root: Path) -> dict[str, float]:
    out = root / "gallery.png"
    started = time.perf_counter()
    child = subprocess.run(
        [sys.executable, "-c", CHILD, str(root), str(out)],
        check=True,
        capture_output=True,
        text=True,
    )
    seconds = time.perf_counter() - started
    peak_kb = int(child.stdout.split()[-1])
    with Image.open(out) as image:  # Pillow opens it (no decompression-bomb refusal)
        width, height = image.size
        image.load()
    return {
        "seconds": round(seconds, 2),
        "peak_mb": round(peak_kb / 1024, 1),
        "width": width,
        "height": height,
        "png_mb": round(out.stat().st_size / 2**20, 2),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", default="1000,10000")
    args = parser.parse_args()
    sizes = [int(n) for n in args.plants.split(",")]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        files = template(Path(tmp) / "template")
        for n in sizes:
            root = Path(tmp) / f"d{n}"
            make_dataset(root, n, files)
            rows.append({"plants": n, **measure(root)})
            print(rows[-1], flush=True)
    lines = [
        "## Gallery of a large dataset (`benches/bench_gallery.py`)",
        "",
        f"Command: `{' '.join(['python benches/bench_gallery.py', *sys.argv[1:]])}`. "
        "`plantdreamer gallery` of a dataset of N finished plants (each with run.json, "
        "a transforms.json of 120 views and a 512 px render and label preview), in a fresh "
        "process: wall time with start-up and imports, that process's peak resident "
        "memory, and the sheet, which Pillow opens.",
        "",
        f"Host: {host_line()}.",
        "",
        "| plants | wall time (s) | peak memory (MB) | sheet (px) | PNG (MB) |",
        "|---|---|---|---|---|",
    ]
    lines += [
        f"| {r['plants']:,} | {r['seconds']} | {r['peak_mb']} | {r['width']} x {r['height']} "
        f"| {r['png_mb']} |"
        for r in rows
    ]
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "gallery.md").write_text("\n".join(lines) + "\n")
    (RESULTS / "gallery.json").write_text(json.dumps(rows, indent=2) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
