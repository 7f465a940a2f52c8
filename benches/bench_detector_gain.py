"""What randomised views buy a detector: the same plants exported (a) as the orbit on grey
(the default) and (b) with the random rig over background photos, plus trays of them, a
small YOLO-seg trained from scratch on each for the same steps (the same number of images,
epochs and batch), both scored on held-out plants in conditions neither saw in that form:
top-down views over held-out photos, and trays of held-out plants seen from the side over
held-out photos.

Plants: L-System bean, mint and kale in turn, `--guidance none --steps 0` (their colours
are the L-System's, no diffusion), trained once and rendered per variant with `render
--labels` (a) or with the rig and photos (b), the trays with `make_scene`. Photos:
``benches/view_photos.py`` (training and held-out sets share no image). YOLO: Ultralytics'
``yolo11n-seg.yaml`` built from scratch, offline (no download: the network is closed in its
process, as ``tests/ultralytics_train.py`` runs it), on the CPU; scored by its own ``val``:
mask mAP50-95 of the leaf class and of all four classes.

    python benches/bench_detector_gain.py [--plants 40] [--held-out 8] [--views 8]
        [--size 160] [--epochs 20] [--batch 16] [--points 20000] [--work DIR] [--device cpu]
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
from host import host_line
from view_photos import HELD_OUT, TRAINING, write_photos

RESULTS = Path(__file__).resolve().parent / "results"
SPECIES = ("bean", "mint", "kale")
CLASSES = {0: "leaf", 1: "stem", 2: "pot", 3: "soil"}
TRAY = 4  # plants per tray


def make_plants(root: Path, count: int, first_seed: int, points: int) -> list[Path]:
    """``count`` plants, the species in turn, trained without guidance, no views yet."""
    import plantdreamer

    plants: list[Path] = []
    for k, species in enumerate(SPECIES):
        n = len(range(k, count, len(SPECIES)))
        if not n:
            continue
        seeds = f"{first_seed}-{first_seed + n - 1}"
        made = plantdreamer.generate(
            root / species, species=species, seeds=seeds, guidance="none", steps=0,
            points=points, eval_views=0, turntable="none", quiet=True,
        )  # fmt: skip
        plants += [p.folder for p in (made if isinstance(made, list) else [made])]
    return plants


def render(plant: Path, out: Path, size: int, views: int, *options: str) -> Path:
    from plantdreamer.cli import main

    args = ["render", str(plant), "--labels", "--out", str(out), "--resolution", str(size),
            "--eval-views", str(views), "--turntable", "none", *options]  # fmt: skip
    main(args, standalone_mode=False)
    return out


def trays(plants: list[Path], out: Path, count: int, seed0: int, **views) -> list[Path]:
    import numpy as np

    from plantdreamer.scenes import make_scene

    made = []
    for t in range(count):
        rng = np.random.default_rng([seed0, t])
        picks = rng.choice(len(plants), TRAY, replace=len(plants) < TRAY)
        chosen = [plants[int(i)] for i in picks]
        made.append(make_scene(chosen, out / f"tray{t:03d}", seed=seed0 + t, **views).folder)
    return made


def yolo_set(folders: list[Path], root: Path, split: str) -> int:
    """Hard-links the YOLO images and labels of ``folders`` into ``root``/images|labels/split."""
    count = 0
    for folder in folders:
        for image in sorted((folder / "yolo" / "images").glob("*.png")):
            name = f"{folder.parent.name}_{folder.name}__{image.stem}"
            label = folder / "yolo" / "labels" / f"{image.stem}.txt"
            for kind, source, suffix in (("images", image, ".png"), ("labels", label, ".txt")):
                target = root / kind / split / f"{name}{suffix}"
                target.parent.mkdir(parents=True, exist_ok=True)
                os.link(source, target)
            count += 1
    return count


def data_yaml(root: Path, train: str, val: str) -> Path:
    path = root / f"{train}-{val}.yaml"
    names = "\n".join(f"  {i}: {n}" for i, n in CLASSES.items())
    path.write_text(f"path: {root}\ntrain: images/{train}\nval: images/{val}\nnames:\n{names}\n")
    return path


CHILD = r"""
import json, os, socket, sys, shutil
from pathlib import Path
def closed(*a, **k):
    raise OSError("no network in the bench")
socket.getaddrinfo = socket.create_connection = socket.socket.connect = closed
from matplotlib import font_manager
from ultralytics import YOLO
from ultralytics.utils import USER_CONFIG_DIR
shutil.copyfile(font_manager.findfont("DejaVu Sans"), Path(USER_CONFIG_DIR) / "Arial.ttf")
job = json.loads(sys.argv[1])
model = YOLO("yolo11n-seg.yaml")
model.train(data=job["train"], epochs=job["epochs"], imgsz=job["size"], batch=job["batch"],
            pretrained=False, amp=False, plots=False, val=False, seed=0, deterministic=True,
            workers=0, device=job["device"], project=job["project"], name="run", exist_ok=True,
            verbose=False)
scores = {}
for name, yaml in job["tests"].items():
    m = model.val(data=yaml, imgsz=job["size"], batch=job["batch"], plots=False,
                  device=job["device"], workers=0, verbose=False, project=job["project"],
                  name=name)
    leaf = list(m.seg.ap_class_index).index(0) if 0 in list(m.seg.ap_class_index) else None
    scores[name] = {"leaf": float(m.seg.maps[0]) if leaf is not None else 0.0,
                    "all": float(m.seg.map), "leaf_box": float(m.box.maps[0])}
print("SCORES " + json.dumps(scores))
"""


def train_and_score(job: dict, settings: Path) -> dict:
    env = {**os.environ, "YOLO_OFFLINE": "1", "YOLO_CONFIG_DIR": str(settings)}
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", CHILD, json.dumps(job)], env=env,
                          capture_output=True, text=True)  # fmt: skip
    if done.returncode:
        raise SystemExit(f"YOLO failed:\n{done.stdout[-2000:]}\n{done.stderr[-4000:]}")
    line = next(x for x in done.stdout.splitlines() if x.startswith("SCORES "))
    return {"scores": json.loads(line[7:]), "seconds": time.perf_counter() - started}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", type=int, default=40)
    parser.add_argument("--held-out", type=int, default=8)
    parser.add_argument("--views", type=int, default=8, help="(a)'s views per plant")
    parser.add_argument("--size", type=int, default=160, help="render and YOLO image size")
    parser.add_argument("--epochs", type=int, default=20)
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--points", type=int, default=20000)
    parser.add_argument("--work", help="keep the plants, views and runs here")
    parser.add_argument("--device", default="cpu", help="where YOLO trains (cpu, 0, ...)")
    args = parser.parse_args()
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="detector_gain_"))
    size, views = args.size, args.views
    t0 = time.perf_counter()
    photos = write_photos(work / "photos" / "training", TRAINING)
    unseen = write_photos(work / "photos" / "held_out", HELD_OUT)
    train = make_plants(work / "plants", args.plants, 0, args.points)
    held = make_plants(work / "held_out_plants", args.held_out, 1000, args.points)
    # (b): three quarters of (a)'s images are plant views, a quarter tray views.
    tray_views = views
    tray_count = max(1, args.plants * views // 4 // tray_views)
    plant_views = (args.plants * views - tray_count * tray_views) // args.plants
    random = ["--rig", "random", "--background-images", str(photos)]
    a = [render(p, work / "a" / p.name, size, views) for p in train]
    b = [render(p, work / "b" / p.name, size, plant_views, *random, "--seed", str(i))
         for i, p in enumerate(train)]  # fmt: skip
    b += trays(train, work / "b_trays", tray_count, 0, rig="random",
               background_images=str(photos), eval_views=tray_views, resolution=size)  # fmt: skip
    top = [render(p, work / "test_top" / p.name, size, 4, "--rig", "top-down",
                  "--background-images", str(unseen), "--seed", str(500 + i))
           for i, p in enumerate(held)]  # fmt: skip
    side = dict(rig="side", rig_elevation_deg=(15.0, 35.0), background_images=str(unseen),
                eval_views=4, resolution=size)  # fmt: skip
    tests = {"top-down": top, "trays": trays(held, work / "test_trays", 4, 900, **side)}
    data = work / "yolo"
    counts = {"a": yolo_set(a, data, "a"), "b": yolo_set(b, data, "b")}
    counts |= {name: yolo_set(folders, data, name) for name, folders in tests.items()}
    prepared = time.perf_counter() - t0
    results = {}
    for variant in ("a", "b"):
        job = {
            "train": str(data_yaml(data, variant, "top-down")), "epochs": args.epochs,
            "size": size, "batch": args.batch, "project": str(work / "runs" / variant),
            "device": args.device,
            "tests": {n: str(data_yaml(data, variant, n)) for n in tests},
        }  # fmt: skip
        results[variant] = train_and_score(job, work / "ultralytics")
        print(variant, counts[variant], results[variant], flush=True)
    write_report(args, counts, results, prepared, plant_views, tray_count, tray_views)


def write_report(args, counts, results, prepared, plant_views, tray_count, tray_views) -> None:
    command = " ".join(["python benches/bench_detector_gain.py", *sys.argv[1:]])
    rows = {"a": "(a) orbit on grey", "b": "(b) random rig, photos, trays"}
    lines = [
        "## What randomised views buy a detector (`benches/bench_detector_gain.py`)",
        "",
        f"Command: `{command}`. {args.plants} L-System plants (bean, mint, kale in turn; "
        f"`--guidance none --steps 0 --points {args.points}`), exported (a) as the orbit "
        f"on grey, {args.views} views each ({counts['a']} images), and (b) with `--rig "
        f"random` over 4 training photos, {plant_views} views each, plus {tray_count} trays "
        f"of {TRAY} of them, {tray_views} views each ({counts['b']} images); "
        f"{args.size} px. YOLO11n-seg from scratch (`yolo11n-seg.yaml`, offline, on "
        f"{'the CPU' if args.device == 'cpu' else 'device ' + args.device}), "
        f"{args.epochs} epochs at batch {args.batch} on each: the same steps. Scored by "
        f"Ultralytics' `val` on {args.held_out} held-out plants: top-down views over 3 "
        f"held-out photos ({counts['top-down']} images) and 4 trays of them seen from the "
        f"side (elevation 15-35 deg) over the held-out photos ({counts['trays']} images). "
        "Mask mAP50-95 of the leaf class (all four classes in brackets).",
        "",
        f"Host: {host_line()}. Plants and views: {prepared / 60:.1f} min.",
        "",
        "| training set | top-down, held-out photos | trays, held-out photos | training (min) |",
        "|---|---|---|---|",
    ]
    for variant, label in rows.items():
        s = results[variant]["scores"]
        cells = [f"{s[t]['leaf']:.4f} ({s[t]['all']:.4f})" for t in ("top-down", "trays")]
        lines.append(f"| {label} | {' | '.join(cells)} | {results[variant]['seconds'] / 60:.1f} |")
    lines.append("")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "detector_gain.md").write_text("\n".join(lines))
    (RESULTS / "detector_gain.json").write_text(
        json.dumps(
            {"args": vars(args), "counts": counts, "results": results, "prepared_s": prepared},
            indent=2,
        )
        + "\n"
    )
    print("\n".join(lines))


if __name__ == "__main__":
    main()
