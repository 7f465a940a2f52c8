"""SOR with two builds of the native module, interleaved in one process, plus Open3D
(not run by run_all.py: it needs the two builds).

    python benches/compare_sor_builds.py OLD.so NEW.so [--rounds 3] [--threads 2] [--no-open3d]

For judging a kNN change on a shared machine: each round runs the old build, the new
build and Open3D 0.20 one after the other on the bench cloud of bench_pointcloud.py (1M
points, k = 20, std 2.0), so load changes hit all three alike. Prints the minimum and
median wall and CPU seconds of each and checks the three kept sets are identical.
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_pointcloud import cloud


def load(name: str, path: str):
    spec = importlib.util.spec_from_file_location(f"{name}._core", path)
    if spec is None or spec.loader is None:
        raise SystemExit(f"error: cannot load {path}")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("old")
    ap.add_argument("new")
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument(
        "--no-open3d", action="store_true", help="old vs new only (Open3D takes ~10x longer)"
    )
    args = ap.parse_args()
    old, new = load("sor_old", args.old), load("sor_new", args.new)
    p, _ = cloud(args.points)
    runs = {
        "old": lambda: old.remove_statistical_outliers(p, 20, 2.0, args.threads),
        "new": lambda: new.remove_statistical_outliers(p, 20, 2.0, args.threads),
    }
    try:
        if args.no_open3d:
            raise ImportError
        import open3d as o3d

        peer = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p.astype(np.float64)))
        runs["Open3D"] = lambda: np.sort(np.asarray(peer.remove_statistical_outlier(20, 2.0)[1]))
    except ImportError:
        if not args.no_open3d:
            print("note: Open3D is not installed; old vs new only")
    wall: dict[str, list[float]] = {k: [] for k in runs}
    cpu: dict[str, list[float]] = {k: [] for k in runs}
    kept: dict[str, np.ndarray] = {}
    for _ in range(args.rounds):
        for name, run in runs.items():
            c, t = time.process_time(), time.perf_counter()
            kept[name] = np.asarray(run())
            wall[name].append(time.perf_counter() - t)
            cpu[name].append(time.process_time() - c)
    same = all(np.array_equal(kept["new"], v) for v in kept.values())
    for name in runs:
        print(
            f"{name:7s} wall min {min(wall[name]):.3f} med {statistics.median(wall[name]):.3f} s"
            f"   CPU min {min(cpu[name]):.3f} med {statistics.median(cpu[name]):.3f} s"
        )
    for name in ("old", "new"):
        if "Open3D" in runs:
            o = wall["Open3D"]
            print(
                f"Open3D / {name}: wall min {min(o) / min(wall[name]):.1f}x, "
                f"median {statistics.median(o) / statistics.median(wall[name]):.1f}x"
            )
    print(
        f"old / new: wall min {min(wall['old']) / min(wall['new']):.2f}x, median "
        f"{statistics.median(wall['old']) / statistics.median(wall['new']):.2f}x; "
        f"kept sets {'identical' if same else 'DIFFERENT'} ({len(kept['new']):,} kept)"
    )
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
