"""Point-cloud benchmark: plantdreamer vs Open3D 0.20 (SOR, voxel grid) and vs plyfile +
numpy (binary PLY read/write), on 1M coloured points with 2% outliers.

    python benches/bench_pointcloud.py [--points 1000000] [--repeat 3] [--threads 1,2]

Writes benches/results/pointcloud.md and pointcloud.json. Each timing is the minimum of
--repeat runs (the machine is shared; the minimum is the least disturbed run). Outputs are
checked for equality with the peer in the same run; a mismatch fails the script.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from plantdreamer import _core
from plantdreamer import pointcloud as pc
from plantdreamer.cloud import PointCloud
from plantdreamer.io import read_ply, write_ply

RESULTS = Path(__file__).resolve().parent / "results"
SOR_TARGET = 10.0  # issue 20: SOR at least 10x Open3D 0.20 on 1M points


def cloud(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A noisy plant-sized surface (ellipsoid shell, 1 m tall) plus 2% uniform outliers."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    p = v * [0.3, 0.2, 0.5] + rng.normal(scale=0.003, size=(n, 3))
    m = n // 50
    p[:m] = rng.uniform(-0.7, 0.7, size=(m, 3))
    return p.astype(np.float32), rng.uniform(size=(n, 3)).astype(np.float32)


class Timing(float):
    """Minimum wall-clock seconds; ``cpu`` is the minimum process CPU seconds (all threads),
    which other jobs on a shared machine disturb much less than wall-clock time."""

    cpu: float


def best(f, repeat: int) -> tuple[Timing, object]:
    walls, cpus, out = [], [], None
    for _ in range(repeat):
        c, t = time.process_time(), time.perf_counter()
        out = f()
        walls.append(time.perf_counter() - t)
        cpus.append(time.process_time() - c)
    timing = Timing(min(walls))
    timing.cpu = min(cpus)
    return timing, out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--threads", default="1,2", help="comma-separated thread counts to show")
    args = ap.parse_args()
    threads = [int(t) for t in args.threads.split(",") if t]
    p, c = cloud(args.points)
    extent = float((p.max(axis=0) - p.min(axis=0)).max())
    rows: list[tuple[str, str, Timing, Timing | None, str]] = []
    facts: dict[str, object] = {"points": args.points, "extent": extent}

    try:
        import open3d as o3d

        o3d_version = o3d.__version__
        o3d_cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p.astype(np.float64)))
        o3d_cloud.colors = o3d.utility.Vector3dVector(c.astype(np.float64))
    except ImportError:
        o3d = None
        o3d_version = "not installed"

    # --- statistical outlier removal ---
    t_ours, kept = best(lambda: pc.remove_statistical_outliers(p, 20, 2.0), args.repeat)
    per_thread = {
        t: best(lambda t=t: pc.remove_statistical_outliers(p, 20, 2.0, threads=t), args.repeat)[0]
        for t in threads
    }
    t_o3d, same = None, "-"
    if o3d is not None:
        t_o3d, (_, ref) = best(
            lambda: o3d_cloud.remove_statistical_outlier(nb_neighbors=20, std_ratio=2.0),
            args.repeat,
        )
        same = "identical" if np.array_equal(kept, np.sort(np.asarray(ref))) else "DIFFERENT"
    rows.append(("SOR k=20, std 2.0", "Open3D", t_ours, t_o3d, f"{same} ({len(kept):,} kept)"))
    facts["sor_threads"] = per_thread

    # --- voxel grid: at 1% of the extent (the setting), and 0.2% (many voxels) ---
    for fraction in (0.01, 0.002):
        voxel = fraction * extent
        t_ours, (vp, vc) = best(lambda v=voxel: pc.voxel_downsample(p, v, c), args.repeat)
        if fraction == 0.01:
            facts["voxel_threads"] = {
                t: best(lambda t=t, v=voxel: pc.voxel_downsample(p, v, c, threads=t), args.repeat)[
                    0
                ]
                for t in threads
            }
        t_o3d, same = None, "-"
        if o3d is not None:
            t_o3d, down = best(lambda v=voxel: o3d_cloud.voxel_down_sample(v), args.repeat)
            rp = np.asarray(down.points)
            origin = p.min(axis=0).astype(np.float64) - voxel / 2
            order = np.lexsort(np.floor((rp - origin) / voxel).T[::-1])
            ours64, _ = pc.voxel_downsample(p.astype(np.float64), voxel, c)
            ok = len(rp) == len(vp) and np.array_equal(ours64, rp[order])
            ok = ok and np.array_equal(vc, np.asarray(down.colors)[order].astype(np.float32))
            same = "identical" if ok else "DIFFERENT"
        rows.append(
            (
                f"voxel grid, {fraction:.1%} of extent",
                "Open3D",
                t_ours,
                t_o3d,
                f"{same} ({len(vp):,} voxels)",
            )
        )

    # --- binary PLY ---
    import plyfile

    with tempfile.TemporaryDirectory() as tmp:
        ours_path, peer_path = os.path.join(tmp, "ours.ply"), os.path.join(tmp, "peer.ply")
        pcl = PointCloud(p, c)
        t_w, _ = best(lambda: write_ply(ours_path, pcl), args.repeat)

        def peer_write() -> None:
            data = np.empty(
                len(p),
                dtype=[(n, "f4") for n in "xyz"] + [(n, "u1") for n in ("red", "green", "blue")],
            )
            for i, n in enumerate("xyz"):
                data[n] = p[:, i]
            rgb = np.round(np.clip(c, 0, 1) * 255).astype(np.uint8)
            for i, n in enumerate(("red", "green", "blue")):
                data[n] = rgb[:, i]
            plyfile.PlyData([plyfile.PlyElement.describe(data, "vertex")]).write(peer_path)

        t_pw, _ = best(peer_write, args.repeat)

        def data(path: str) -> bytes:
            raw = Path(path).read_bytes()
            return raw[raw.index(b"end_header\n") + len(b"end_header\n") :]

        same_bytes = data(ours_path) == data(peer_path)
        rows.append((f"write {args.points:,}-point binary PLY", "plyfile + numpy", t_w, t_pw,
                     "same data bytes" if same_bytes else "data bytes differ"))  # fmt: skip

        t_r, back = best(lambda: read_ply(ours_path), args.repeat)

        def peer_read() -> tuple[np.ndarray, np.ndarray]:
            v = plyfile.PlyData.read(ours_path)["vertex"]
            pos = np.stack([v["x"], v["y"], v["z"]], axis=1)
            col = np.stack([v["red"], v["green"], v["blue"]], axis=1).astype(np.float32) / 255
            return pos, col

        t_pr, (pp, pcol) = best(peer_read, args.repeat)
        ok = np.array_equal(back.positions, pp) and np.array_equal(back.colors, pcol)
        rows.append((f"read {args.points:,}-point binary PLY", "plyfile + numpy", t_r, t_pr,
                     "identical arrays" if ok else "DIFFERENT"))  # fmt: skip

    lines = [
        "## Point clouds: SOR, voxel grid, PLY I/O\n",
        f"`python benches/bench_pointcloud.py --points {args.points} --repeat {args.repeat} "
        f"--threads {args.threads}`: {args.points:,} points with colours (a noisy ellipsoid "
        f"shell, 2% uniform outliers), Open3D {o3d_version} legacy API in the same process, "
        f"{_core.info()['threads']} rayon threads. Minimum of {args.repeat} runs, measured on "
        f"a shared 2-core machine (1-minute load average {os.getloadavg()[0]:.1f} when "
        "written): ratios are what to read, not absolute seconds, and the CPU-time columns "
        "(process CPU seconds summed over threads) are the steadier measure of work. Open3D "
        "timings exclude building its point cloud from numpy; ours include the numpy "
        "hand-over.\n",
        "| operation | peer | plantdreamer (s) | peer (s) | speed-up | CPU s: ours / peer "
        "| CPU ratio | output check |",
        "|---|---|---:|---:|---:|---:|---:|---|",
    ]
    for name, peer, ours, theirs, check in rows:
        ratio = f"{theirs / ours:.1f}x" if theirs else "-"
        peer_t = f"{theirs:.3f}" if theirs else "-"
        cpu = f"{ours.cpu:.3f} / {theirs.cpu:.3f}" if theirs else f"{ours.cpu:.3f} / -"
        cpu_ratio = f"{theirs.cpu / ours.cpu:.1f}x" if theirs else "-"
        lines.append(
            f"| {name} | {peer} | {ours:.3f} | {peer_t} | {ratio} | {cpu} | {cpu_ratio} | {check} |"
        )
        print(
            f"{name:<34} ours {ours:7.3f} s   {peer} {peer_t} s   {ratio}   CPU {cpu_ratio}   {check}"
        )
    sor = rows[0]
    if sor[3]:
        met = "met" if sor[3] / sor[2] >= SOR_TARGET else "not met"
        lines.append(
            f"\nTarget (issue 20): SOR at least {SOR_TARGET:.0f}x Open3D on 1M points, same kept "
            f"set: {sor[3] / sor[2]:.1f}x in wall time here ({met})."
        )
    lines.append("")
    lines.append("Thread scaling (same call with an explicit pool; outputs are bit-identical):\n")
    lines.append("| operation | " + " | ".join(f"{t} thread(s) (s)" for t in threads) + " |")
    lines.append("|---|" + "---:|" * len(threads))
    for key, label in (("sor_threads", "SOR k=20"), ("voxel_threads", "voxel grid")):
        times = facts[key]
        lines.append(f"| {label} | " + " | ".join(f"{times[t]:.3f}" for t in threads) + " |")  # type: ignore[index]
        print(f"{label:<28} " + "  ".join(f"{t} thr {times[t]:.3f} s" for t in threads))  # type: ignore[index]
    lines.append(
        "\nHow: SOR and kNN use a kd-tree (median splits on integer keys that order as the "
        "coordinates, tight node boxes, leaves of up to 64 points) searched in "
        "float64 with nanoflann's distance arithmetic, as in Open3D, so the kept sets are "
        "identical, not just close. Each leaf's points are ordered by further median splits, "
        "so consecutive queries are near neighbours: each starts from a bound taken from the "
        "one before (triangle inequality), at its own leaf, walking up through the sibling "
        "subtrees instead of descending from the root; a leaf's candidates are filtered by a "
        "branch-free bit mask before they enter the neighbour list. SOR needs only the "
        "distances, so its list is a sorted array of the k smallest updated by a branch-free "
        "min/max network (slot i becomes max(slot i-1, min(slot i, d))), and the search is "
        "compiled a second time for AVX2 (chosen at run time, same operations in the same "
        "order, so the same bits). The voxel grid hashes packed voxel keys (each voxel owned "
        "by one worker and summed in input order) and sorts only the occupied voxels, so its "
        "means are Open3D's to the bit and its order is deterministic. With few voxels (1% of "
        "the extent: ~35k) Open3D's own hash map is already fast and the gain is small; it "
        "grows with the voxel count. The PLY reader gathers x/y/z, normals and colours as "
        "[N, 3] blocks straight from the byte buffer; the writer takes [N, k] blocks without "
        "splitting them.\n"
    )
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "pointcloud.md").write_text("\n".join(lines))
    facts["rows"] = [
        {
            "operation": r[0],
            "peer": r[1],
            "ours_s": r[2],
            "peer_s": r[3],
            "ours_cpu_s": r[2].cpu,
            "peer_cpu_s": r[3].cpu if r[3] else None,
            "check": r[4],
        }
        for r in rows
    ]
    (RESULTS / "pointcloud.json").write_text(json.dumps(facts, indent=2, default=str))
    return 1 if any("DIFFERENT" in r[4] for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
