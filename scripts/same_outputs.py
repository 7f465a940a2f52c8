"""Whether two trees of plantdreamer write the same plants: runs the lifecycle's scenarios
through the command line of whichever package ``python`` imports (set PYTHONPATH to pick a
tree), with the known-answer models as SDS guidance on the CPU, and writes one digest per
output file.

    PYTHONPATH=OLD/python python scripts/same_outputs.py run OUT/old
    PYTHONPATH=NEW/python python scripts/same_outputs.py run OUT/new
    python scripts/same_outputs.py compare OUT/old OUT/new

Scenarios: a plant alone, a group of 3 (``--seeds``, overlap on) and a dataset of 4 plants
at 2 per trainer, each fresh and cut then resumed (Ctrl-C once its first checkpoint is
written; the cut run's checkpoint at that step is digested by its tensors, the guidance's
noise state aside, which a checkpoint format may move). ``run.json`` is compared without
its timings, versions and the machine's figures; the rest byte for byte.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "tests" / "data" / "known_answer" / "bean_s0_r64"
SETTINGS = [
    "--points", "3000", "--resolution", "64", "--sds-resolution", "64", "--steps", "60",
    "--checkpoint-every", "10", "--eval-views", "3", "--turntable", "none",
    "--guidance", "sds", "--color-init", "noise", "--device", "cpu",
    "--base-model", str(MODELS / "base"), "--controlnet", str(MODELS / "controlnet"),
]  # fmt: skip
SCENARIOS: dict[str, list[str]] = {
    "alone": ["generate", "--species", "bean", "--seed", "0", *SETTINGS],
    "group": ["generate", "--species", "bean", "--seeds", "0-2", "--overlap", "on", *SETTINGS],
    "dataset": [
        "dataset", "--species", "bean", "--seeds", "0-3", "--plants-per-gpu", "2",
        "--gpus-per-plant", "0", "--cpus-per-plant", "1", "--local-cpus", "2",
        "--allow-empty-split",
        *[f"--set={name[2:]}={value}" for name, value in zip(SETTINGS[::2], SETTINGS[1::2], strict=True)],
    ],
}  # fmt: skip
# run.json's entries that say how and where it ran, not what it made.
UNSTABLE = {"timings_s", "per_step_s", "versions", "threads", "cpu_count", "raster_threads"}
NOISE_KEYS = {"guidance", "guidance_device", "format"}


def command(scenario: str, out: Path) -> list[str]:
    return [sys.executable, "-m", "plantdreamer", *SCENARIOS[scenario], "--out", str(out)]


def run(out: Path, only: list[str]) -> None:
    """Runs the scenarios (``only`` those named, their digests added to the file's)."""
    where = out / "digests.json"
    digests: dict[str, Any] = json.loads(where.read_text()) if where.is_file() else {}
    for scenario in only or SCENARIOS:
        for mode in ("fresh", "cut"):
            folder = out / f"{scenario}-{mode}"
            cmd = command(scenario, folder)
            t0 = time.perf_counter()
            cut_checkpoint = None
            if mode == "fresh":
                subprocess.run(cmd, check=True, capture_output=True)
            else:
                cut_checkpoint = cut_and_resume(cmd, folder, scenario)
            print(f"{scenario} {mode}: {time.perf_counter() - t0:.1f} s", file=sys.stderr)
            digests[f"{scenario}-{mode}"] = {
                "files": folder_digests(folder),
                "cut_checkpoints": cut_checkpoint,
            }
            where.write_text(json.dumps(digests, indent=1, sort_keys=True))


def cut_and_resume(cmd: list[str], folder: Path, scenario: str) -> dict[str, str]:
    """Starts ``cmd``, digests each plant's first checkpoint as it appears, sends Ctrl-C,
    then runs the command again to finish (``generate --resume`` or the same dataset)."""
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    copies = folder.parent / f"{folder.name}-first-checkpoints"
    copies.mkdir(parents=True, exist_ok=True)
    seen: dict[str, Path] = {}
    deadline = time.monotonic() + 600
    while proc.poll() is None and time.monotonic() < deadline:
        for path in sorted(folder.rglob("checkpoint.pt")):
            key = str(path.parent.relative_to(folder))
            if key not in seen:
                copy = copies / f"{len(seen)}.pt"
                try:
                    shutil.copyfile(path, copy)  # an atomic write: whole, or replaced
                except FileNotFoundError:
                    continue
                seen[key] = copy
        if seen and len(seen) >= expected_plants(scenario):
            proc.send_signal(signal.SIGINT)
            break
        time.sleep(0.02)
    _, err = proc.communicate(timeout=600)
    if proc.returncode == 0:
        raise RuntimeError(f"{scenario}: finished before it could be cut")
    if b"interrupted" not in err.lower():
        raise RuntimeError(f"{scenario}: the cut run failed: {err.decode()[-2000:]}")
    if scenario == "dataset":
        again = cmd
    else:
        again = [sys.executable, "-m", "plantdreamer", "generate", "--resume", str(folder)]
    subprocess.run(again, check=True, capture_output=True)
    return {key: checkpoint_digest(copy) for key, copy in seen.items()}


def expected_plants(scenario: str) -> int:
    return {"alone": 1, "group": 3, "dataset": 2}[scenario]


def checkpoint_digest(path: Path) -> str:
    """The step and every tensor of a plant's checkpoint, the noise state aside."""
    import torch

    saved = torch.load(path, map_location="cpu", weights_only=True)
    h = hashlib.sha256()

    def walk(prefix: str, value: Any) -> None:
        if isinstance(value, dict):
            for k in sorted(value):
                if prefix or k not in NOISE_KEYS:
                    walk(f"{prefix}/{k}", value[k])
        elif isinstance(value, (list, tuple)):
            for i, v in enumerate(value):
                walk(f"{prefix}/{i}", v)
        elif isinstance(value, torch.Tensor):
            h.update(prefix.encode())
            h.update(value.contiguous().cpu().numpy().tobytes())
        elif prefix.startswith(("/config", "/events", "/timings")):
            return  # the settings, notes and wall times: compared through run.json
        else:
            h.update(f"{prefix}={value!r}".encode())

    walk("", saved)
    return f"step {saved['step']}: {h.hexdigest()}"


def folder_digests(folder: Path) -> dict[str, str]:
    out = {}
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        rel = str(path.relative_to(folder))
        if path.name == "run.json":
            run = json.loads(path.read_text())
            kept = {k: v for k, v in run.items() if k not in UNSTABLE}
            out[rel] = json.dumps(kept, sort_keys=True)
        elif path.suffix in (".log", ".jsonl") or path.name in ("log.csv",):
            continue  # wall times and hosts
        else:
            out[rel] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


def compare(old: Path, new: Path) -> int:
    a = json.loads((old / "digests.json").read_text())
    b = json.loads((new / "digests.json").read_text())
    bad = 0
    for case in sorted(set(a) | set(b)):
        fa, fb = a.get(case, {}).get("files", {}), b.get(case, {}).get("files", {})
        for rel in sorted(set(fa) | set(fb)):
            if fa.get(rel) != fb.get(rel):
                bad += 1
                what = "only old" if rel not in fb else "only new" if rel not in fa else "differs"
                print(f"{case}: {rel}: {what}")
                if rel.endswith("run.json") and rel in fa and rel in fb:
                    ra, rb = json.loads(fa[rel]), json.loads(fb[rel])
                    for k in sorted(set(ra) | set(rb)):
                        if ra.get(k) != rb.get(k):
                            print(f"    {k}: {str(ra.get(k))[:150]} -> {str(rb.get(k))[:150]}")
        ca, cb = a.get(case, {}).get("cut_checkpoints"), b.get(case, {}).get("cut_checkpoints")
        if ca != cb:
            bad += 1
            print(f"{case}: cut checkpoints: {ca} -> {cb}")
    print(f"{bad} differences")
    return 1 if bad else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="what", required=True)
    r = sub.add_parser("run")
    r.add_argument("out", type=Path)
    r.add_argument("--only", nargs="*", choices=list(SCENARIOS), default=[])
    c = sub.add_parser("compare")
    c.add_argument("old", type=Path)
    c.add_argument("new", type=Path)
    args = parser.parse_args()
    if args.what == "run":
        args.out.mkdir(parents=True, exist_ok=True)
        run(args.out, args.only)
        return 0
    return compare(args.old, args.new)


if __name__ == "__main__":
    os.environ.setdefault("PYTHONHASHSEED", "0")
    sys.exit(main())
