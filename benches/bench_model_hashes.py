"""What recording a guided run's model files costs (``run.json``'s ``models``,
``guidance/model_files.py``): the record of the committed known-answer models (a base model
and a ControlNet of 11 MB) when its files are hashed, and again in the same process (each
file hashed once per process while unchanged), then SHA-256's rate here on a file in the
page cache, which sets the cost of models read from a folder that is neither the Hugging
Face cache nor an ``hf download --local-dir`` folder (those give their hashes unread).

    python benches/bench_model_hashes.py [--repeats 5] [--mib 256]
"""

from __future__ import annotations

import argparse
import hashlib
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from plantdreamer import digests
from plantdreamer.guidance.model_files import model_files_record

ROOT = Path(__file__).resolve().parent.parent
RESULTS = Path(__file__).resolve().parent / "results"
MODELS = ROOT / "tests" / "data" / "known_answer" / "bean_s0_r64"
# SD 2.1-base's parts and the depth ControlNet in float32, as the README gives them.
FULL_SIZE_GB = 6.6


def time_record(clear: bool) -> float:
    if clear:
        digests._CACHE.clear()
    t0 = time.perf_counter()
    model_files_record(str(MODELS / "base"), str(MODELS / "controlnet"), None)
    return time.perf_counter() - t0


def sha256_rate(mib: int) -> float:
    """Bytes per second of SHA-256 over a file just written (in the page cache)."""
    with tempfile.NamedTemporaryFile() as f:
        block = hashlib.sha256(b"seed").digest() * (1 << 15)  # 1 MiB
        for _ in range(mib):
            f.write(block)
        f.flush()
        t0 = time.perf_counter()
        digests.file_digest(Path(f.name))
        return mib * (1 << 20) / (time.perf_counter() - t0)


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--mib", type=int, default=256)
    args = parser.parse_args()
    time_record(clear=True)  # the files in the page cache, the modules imported
    first, cached, rates = [], [], []
    for _ in range(args.repeats):  # interleaved
        first.append(time_record(clear=True))
        cached.append(time_record(clear=False))
        rates.append(sha256_rate(args.mib))
    record = model_files_record(str(MODELS / "base"), str(MODELS / "controlnet"), None)
    files = sum(len(m["files"]) for m in record)
    size = sum(f["bytes"] for m in record for f in m["files"])
    rate = statistics.median(rates)

    def ms(values: list[float]) -> str:
        return f"{min(values) * 1e3:.1f} / {statistics.median(values) * 1e3:.1f}"

    command = "python benches/bench_model_hashes.py" + (
        f" --repeats {args.repeats} --mib {args.mib}" if (args.repeats, args.mib) != (5, 256)
        else ""
    )  # fmt: skip
    load = os.getloadavg()[0]
    text = (
        "## Model files recorded by a guided run (`benches/bench_model_hashes.py`)\n\n"
        f"Command: `{command}`. The `models` record of `run.json` for the committed "
        f"known-answer models ({files} files, {size / 1e6:.1f} MB): with every file hashed "
        "(first in a process), and again in the same process (the digests kept by path, size, "
        f"time and inode); min / median of {args.repeats}, interleaved with SHA-256 over a "
        f"{args.mib} MiB file in the page cache, on the shared 2-core machine at a load "
        f"average of {load:.1f}.\n\n"
        "| what | ms (min / median) |\n|---|---|\n"
        f"| record, files hashed | {ms(first)} |\n"
        f"| record, same process again | {ms(cached)} |\n\n"
        f"SHA-256 here: {rate / 1e9:.2f} GB/s (median; {min(rates) / 1e9:.2f} to "
        f"{max(rates) / 1e9:.2f}). At that rate the {FULL_SIZE_GB} GB of SD 2.1-base and the "
        f"depth ControlNet in float32 would take about {FULL_SIZE_GB * 1e9 / rate:.0f} s once "
        "per process from a plain folder (plus reading them from disk); from the Hugging Face "
        "cache or a `hf download --local-dir` folder nothing is read: the hub's SHA-256 of "
        "each weight file is its blob's name or the download's record. A dataset worker "
        "records each file once for all its plants.\n"
    )
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "model_hashes.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
