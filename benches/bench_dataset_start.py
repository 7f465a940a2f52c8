"""How soon `plantdreamer dataset` starts on one machine, and how soon a mistake is refused.

Four measurements, each from a cold process (the time a user waits), in rounds that
interleave the variants compared so that the shared machine's load falls on all alike;
min and median over the rounds:

1. **A worker ready for its first plant**: from launching a driver to a worker that has
   imported the pipeline (torch included), through a local Ray (as `dataset --address
   local` starts it; and as lean as `ray.init` allows: no worker prestarted, no metrics,
   no usage report, the smallest object store) or through the local pool's worker process
   (`python -m plantdreamer.dataset.local_worker`'s imports).
2. **A dataset of two `--guidance none` plants**: from launching the command to the first
   plant's start and end (the manifest's timestamps), on the local pool and on
   `--address local`.
3. **A rerun of a finished 4-plant dataset** (nothing to train; the exports are remade).
4. **Mistakes** (`generate --species beam`, `--device cuda --guidance none` without a GPU,
   `--steps -3`, `dataset --species beam`): the command's wall time until its error, this
   tree against ``--baseline DIR`` (an earlier checkout's ``python/``), interleaved.

    python benches/bench_dataset_start.py [--rounds N] [--baseline DIR/python]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

BENCHES = Path(__file__).resolve().parent
RESULTS = BENCHES / "results"
sys.path.insert(0, str(BENCHES))
from host import host_line  # noqa: E402

PYTHON_DIR = BENCHES.parent / "python"
TINY = ["--guidance", "none", "--steps", "2", "--points", "2000", "--resolution", "64",
        "--eval-views", "2", "--set", "turntable=none", "--allow-empty-split", "--quiet"]  # fmt: skip
# A driver that starts a local Ray and one worker actor that imports the pipeline, then
# prints "ready"; ``lean`` leaves out what ray.init lets a caller leave out.
RAY_WORKER = """
import os, sys
lean = sys.argv[1] == "lean"
if lean:
    os.environ["RAY_USAGE_STATS_ENABLED"] = "0"
import ray
options = dict(address="local", num_cpus=2, num_gpus=0, include_dashboard=False,
               _node_ip_address="127.0.0.1", log_to_driver=False, logging_level="WARNING")
if lean:
    options.update(object_store_memory=80 * 2**20, _system_config={
        "enable_worker_prestart": False, "prestart_worker_first_driver": False,
        "enable_metrics_collection": False})
os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
ray.init(**options)

@ray.remote(num_cpus=1)
class Worker:
    def ready(self):
        import plantdreamer.dataset.worker, plantdreamer.pipeline.trainer  # noqa: F401
        return os.getpid()

worker = Worker.remote()
ray.get(worker.ready.remote())
print("ready", flush=True)
ray.shutdown()
"""
# The local pool's driver side as the command has it when it starts a worker, then the
# worker's side: the process `local_pool` starts, with the imports a unit makes.
POOL_WORKER = """
import subprocess, sys
import plantdreamer.dataset.runner  # noqa: F401  (the driver's modules)
code = "import plantdreamer.dataset.local_worker, plantdreamer.pipeline.group"
subprocess.run([sys.executable, "-c", code], check=True)
print("ready", flush=True)
"""


def env_with(python_dir: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(python_dir)}


def until_ready(code: str, *args: str) -> float:
    """Seconds from launching ``code`` to its "ready" line; NaN when it never came (Ray's
    node timed out during its start)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", code, *args], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True, env=env_with(PYTHON_DIR))  # fmt: skip
    assert proc.stdout is not None
    seconds = float("nan")
    for line in proc.stdout:
        if line.strip() == "ready":
            seconds = time.perf_counter() - t0
            break
    proc.wait(timeout=300)
    return seconds


def dataset(out: Path, *extra: str, seeds: str = "0-1") -> dict[str, float]:
    """Seconds from launch to the first plant's start and end, and the whole command."""
    launched = time.time()
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "plantdreamer", "dataset", "--species", "bean", "--seeds",
           seeds, *TINY, *extra, "--out", str(out)]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, env=env_with(PYTHON_DIR))
    wall = time.perf_counter() - t0
    if done.returncode != 0:  # a local Ray that timed out while starting, on a loaded machine
        nan = float("nan")
        return {"start": nan, "done": nan, "wall": nan}
    records = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines()]
    assert all(r["status"] == "done" for r in records), records
    ran = [r for r in records if "started" in r]
    return {
        "start": min(r["started"] for r in ran) - launched if ran else float("nan"),
        "done": min(r["finished"] for r in ran) - launched if ran else float("nan"),
        "wall": wall,
    }


# Small, so that a tree that does not refuse it (d0ac9b2 ran the plant on the CPU) runs a
# plant of seconds.
NO_GUIDANCE_CUDA = ["generate", "--species", "bean", "--device", "cuda", "--guidance", "none",
                    "--points", "1000", "--steps", "1", "--eval-views", "1", "--resolution",
                    "32", "--turntable", "none"]  # fmt: skip
MISTAKES = {
    "generate --species beam": ["generate", "--species", "beam"],
    "generate --device cuda --guidance none": NO_GUIDANCE_CUDA,
    "generate --steps -3": ["generate", "--species", "bean", "--steps", "-3"],
    "dataset --species beam": ["dataset", "--species", "beam"],
}


def mistake(args: list[str], python_dir: Path, out: Path) -> float:
    """Seconds to the error; negative: the command was not refused and ran (that long)."""
    t0 = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "plantdreamer", *args, "--out", str(out), "--overwrite"
         if args[0] == "generate" else "--quiet"],
        capture_output=True, text=True, env={**env_with(python_dir), "CUDA_VISIBLE_DEVICES": ""},
    )  # fmt: skip
    seconds = time.perf_counter() - t0
    if done.returncode == 0:
        return -seconds
    assert done.returncode == 1 and "error:" in done.stderr, done.stderr[-500:]
    return seconds


def _commit(python_dir: Path) -> str:
    """The short commit of the checkout holding ``python_dir``, else its path."""
    done = subprocess.run(["git", "-C", str(python_dir), "rev-parse", "--short", "HEAD"],
                          capture_output=True, text=True)  # fmt: skip
    return done.stdout.strip() or str(python_dir)


def cell(values: list[float]) -> str:
    if values and all(v < 0 for v in values):  # not refused: the run's own time
        return f"not refused: ran, {-statistics.median(values):.1f}"
    ok = [v for v in values if v == v]  # NaN: never ready
    failed = (
        f" ({len(values) - len(ok)} of {len(values)} failed to start)"
        if len(ok) < len(values)
        else ""
    )
    if not ok:
        return "never" + failed
    return f"{min(ok):.1f} / {statistics.median(ok):.1f}{failed}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--baseline", type=Path, help="an earlier checkout's python/ folder")
    args = parser.parse_args()
    ready: dict[str, list[float]] = {"ray": [], "ray-lean": [], "pool": []}
    first: dict[str, list[dict[str, float]]] = {"pool": [], "ray": []}
    rerun: list[float] = []
    errors: dict[tuple[str, str], list[float]] = {}
    loads = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        dataset(tmp / "four", seeds="0-3")  # the finished dataset the reruns find
        for r in range(args.rounds):
            ready["ray"].append(until_ready(RAY_WORKER, "default"))
            ready["pool"].append(until_ready(POOL_WORKER))
            ready["ray-lean"].append(until_ready(RAY_WORKER, "lean"))
            first["pool"].append(dataset(tmp / f"pool{r}"))
            first["ray"].append(dataset(tmp / f"ray{r}", "--address", "local"))
            t0 = time.perf_counter()
            dataset(tmp / "four", seeds="0-3")
            rerun.append(time.perf_counter() - t0)
            for name, command in MISTAKES.items():
                trees = {"this tree": PYTHON_DIR}
                if args.baseline is not None:
                    trees["baseline"] = args.baseline
                for version, python_dir in trees.items():
                    seconds = mistake(command, python_dir, tmp / "m")
                    errors.setdefault((name, version), []).append(seconds)
            loads.append(os.getloadavg()[0])
    baseline = _commit(args.baseline) if args.baseline is not None else None
    versions = [v for v in ("this tree", "baseline") if any(k[1] == v for k in errors)]
    header = (
        f"Command: `python benches/bench_dataset_start.py --rounds {args.rounds}"
        + (f" --baseline DIR/python` (DIR: a checkout of {baseline})" if baseline else "`")
        + f". Host: {host_line()}. The shared machine had other work on it (1-minute load "
        f"average {min(loads):.1f} to {max(loads):.1f} between rounds): each cell is min / "
        "median seconds over the rounds, the variants interleaved round by round, every time "
        "from the launch of a cold process."
    )
    lines = [
        "## Dataset start and early refusals (`benches/bench_dataset_start.py`)\n",
        textwrap.fill(header, 90) + "\n",
        "A worker ready for its first plant (imported the pipeline, torch included):\n",
        "| through | seconds (min / median) |",
        "|---|---|",
        f"| a local Ray, as `--address local` starts it | {cell(ready['ray'])} |",
        f"| a local Ray as lean as `ray.init` allows | {cell(ready['ray-lean'])} |",
        f"| the local pool's worker process | {cell(ready['pool'])} |",
        "",
        "Two `--guidance none` plants (2,000 points, 2 steps, 2 views at 64 px), from launch (a",
        "plant starts when a worker takes it; its torch import follows):\n",
        "| where | first plant starts | first plant done | whole command |",
        "|---|---|---|---|",
    ]
    for where, label in (("pool", "local pool (no `--address`)"), ("ray", "`--address local`")):
        runs = first[where]
        lines.append(
            f"| {label} | {cell([x['start'] for x in runs])} | {cell([x['done'] for x in runs])} "
            f"| {cell([x['wall'] for x in runs])} |"
        )
    lines += [
        "",
        f"A rerun of the finished 4-plant dataset (nothing to train; exports remade): "
        f"{cell(rerun)} s.\n",
        "Mistakes, launch to the error line (no GPU visible):\n",
        "| command | "
        + " | ".join(v if v != "baseline" else baseline or v for v in versions)
        + " |",
        "|---|" + "---|" * len(versions),
    ]
    for name in MISTAKES:
        row = [cell(errors[(name, v)]) for v in ("this tree", "baseline") if (name, v) in errors]
        lines.append(f"| `{name}` | " + " | ".join(row) + " |")
    lines.append("")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "dataset_start.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
