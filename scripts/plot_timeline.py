"""Draws a Chrome trace of one training step (``benches/bench_throughput.py --trace``): one
lane per host thread and one per GPU stream, on one time axis, so it is seen what the GPU
waits for and what the host waits for.

    python scripts/plot_timeline.py step.json docs/images/step_timeline.png --title "..."

A lane shows the step's named ranges (phases, each plant's render and backward, Adam) as
coloured bars, nested ranges thinner inside their parents, and below them the thread's
torch operators (or the stream's kernels and copies) as grey marks. Threads with no named
range and less than 1% of the step in operators are left out (idle pool threads).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

COLOURS = {
    "raster": "#4c72b0",
    "render": "#4c72b0",
    "depth": "#8172b2",
    "guidance": "#dd8452",
    "backward": "#55a868",
    "optimizer": "#c44e52",
}
DEVICE_CATEGORIES = ("kernel", "gpu_memcpy", "gpu_memset")


def colour(name: str) -> str:
    word = name.split()[0].lower().split(".")[0]
    if word.startswith("optimizer"):
        return COLOURS["optimizer"]
    return COLOURS.get(word, "#999999")


def lanes(events: list[dict[str, Any]]) -> dict[tuple[Any, Any], dict[str, list]]:
    """(pid, tid) -> {"ranges": [(start, dur, name)], "ops": [(start, dur)]}, device lanes
    marked by their category."""
    out: dict[tuple[Any, Any], dict[str, list]] = defaultdict(lambda: {"ranges": [], "ops": []})
    for e in events:
        if e.get("ph") != "X" or "dur" not in e:
            continue
        cat, key = e.get("cat", ""), (e.get("pid"), e.get("tid"))
        if cat == "user_annotation" or cat == "gpu_user_annotation":
            out[key]["ranges"].append((e["ts"], e["dur"], e["name"]))
        elif cat == "cpu_op" or cat in DEVICE_CATEGORIES:
            out[key]["ops"].append((e["ts"], e["dur"]))
            out[key]["device"] = [cat in DEVICE_CATEGORIES]
    return out


def depths(ranges: list[tuple[float, float, str]]) -> list[int]:
    """Nesting depth of each range (ranges sorted by start)."""
    stack: list[float] = []
    out = []
    for start, dur, _ in ranges:
        while stack and stack[-1] <= start:
            stack.pop()
        out.append(len(stack))
        stack.append(start + dur)
    return out


def plot(trace: Path, out: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    events = json.loads(trace.read_text())["traceEvents"]
    found = lanes(events)
    spans = [(s, s + d) for lane in found.values() for s, d, *_ in lane["ranges"] + lane["ops"]]
    if not spans:
        raise SystemExit(f"error: {trace} holds no timed events")
    t0 = min(s for s, _ in spans)
    total = max(e for _, e in spans) - t0
    host = [k for k, v in found.items() if not v.get("device", [False])[0]]
    device = [k for k, v in found.items() if v.get("device", [False])[0]]
    busy = {k: sum(d for _, d in found[k]["ops"]) for k in found}
    host = [k for k in host if found[k]["ranges"] or busy[k] > 0.01 * total]
    host.sort(key=lambda k: (not found[k]["ranges"], min(s for s, *_ in found[k]["ranges"]
                                                        or found[k]["ops"])))  # fmt: skip
    order = host + sorted(device, key=str)
    fig, ax = plt.subplots(figsize=(12, 0.55 * len(order) + 1.4))
    for row, key in enumerate(order):
        y = len(order) - 1 - row
        lane = found[key]
        ranges = sorted(lane["ranges"])
        for (start, dur, name), depth in zip(ranges, depths(ranges), strict=True):
            inset = 0.1 * min(depth, 3)
            ax.broken_barh([((start - t0) / 1e3, dur / 1e3)], (y + 0.25 + inset, 0.65 - 2 * inset),
                           facecolors=colour(name), edgecolors="white", linewidth=0.3)  # fmt: skip
        ops = [((s - t0) / 1e3, max(d / 1e3, total / 1e3 / 2000)) for s, d in lane["ops"]]
        ax.broken_barh(ops, (y + 0.02, 0.18), facecolors="#555555")
    names = []
    for i, (pid, tid) in enumerate(order):
        if (pid, tid) in device:
            names.append(f"GPU {pid} stream {tid}")
        else:
            names.append("main thread" if i == 0 else f"host thread {tid}")
    ax.set_yticks([len(order) - 1 - i + 0.5 for i in range(len(order))], names)
    ax.set_xlabel("ms from the step's first event")
    ax.set_xlim(0, total / 1e3)
    handles = [plt.Rectangle((0, 0), 1, 1, color=c) for c in COLOURS.values()]
    handles.append(plt.Rectangle((0, 0), 1, 1, color="#555555"))
    ax.legend(handles, [*COLOURS, "torch ops / kernels"], loc="upper center",
              bbox_to_anchor=(0.5, -0.18), ncol=6, frameon=False)  # fmt: skip
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    from plantdreamer.atomic import atomic_path

    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=110, format=out.suffix.lstrip(".") or "png")
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("trace", type=Path, help="Chrome trace JSON (bench_throughput.py --trace)")
    p.add_argument("out", type=Path, help="image to write (.png or .svg)")
    p.add_argument("--title", default="one training step")
    args = p.parse_args(argv)
    if not args.trace.is_file():
        raise SystemExit(f"error: no trace at {args.trace}")
    plot(args.trace, args.out, args.title)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
