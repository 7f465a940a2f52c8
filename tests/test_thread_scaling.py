"""scripts/gpu_checks.py scaling (benches/thread_scaling.py): the run a many-core host makes
with a carried `raster_timing` binary, here on 1 and 2 threads and a small scene."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benches"))

import thread_scaling  # noqa: E402

# `make test`'s `cargo test` builds the examples into debug/ (the test profile, optimised);
# a release build (`cargo build --release --examples`) is used when there is one.
_TARGET = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
BINARY = next(
    (p for p in (_TARGET / f"{profile}/examples/raster_timing" for profile in ("release", "debug"))
     if p.is_file()),
    _TARGET / "release/examples/raster_timing",
)  # fmt: skip

# raster_timing's output with BACKWARD=1 HASH=1 (crates/splat_core/examples/raster_timing.rs).
SAMPLE = """20000 Gaussians @ 256^2, 2 thread(s), 3 calls
forward ms: min 4.50 median 4.80
forward cpu ms: min 8.00 median 8.50
  project ms: min 1.04 median 1.10
  sort ms: min 0.72 median 0.85
  bin ms: min 0.91 median 0.92
  blend ms: min 1.80 median 1.90
gradients hash a4b82ef0c75f3d10
backward ms: min 6.00 median 6.20
backward cpu ms: min 11.00 median 11.50
intersections 29367
image hash 074a5c2a31b6b03f
"""


def test_a_run_is_parsed_into_stages_and_hashes():
    r = thread_scaling.parse_run(SAMPLE)
    assert r["stages_ms"]["forward"] == [4.5, 4.8]
    assert r["stages_ms"]["sort"] == [0.72, 0.85]
    assert r["stages_ms"]["backward"] == [6.0, 6.2]
    assert "cpu" not in r["stages_ms"]
    assert r["hashes"] == {"image": "074a5c2a31b6b03f", "gradients": "a4b82ef0c75f3d10"}
    with pytest.raises(RuntimeError, match="no backward time"):
        thread_scaling.parse_run(SAMPLE.replace("backward ms", "other ms"))


def test_scenes_and_the_identity_check():
    assert thread_scaling.parse_scenes("100000@512, 1000000@768") == [
        (100_000, 512),
        (1_000_000, 768),
    ]
    run = {"scene": "a", "hashes": {"image": "1", "gradients": "2"}}
    other = {"scene": "a", "hashes": {"image": "1", "gradients": "3"}}
    assert thread_scaling.identical_across_threads([run, dict(run)])
    assert not thread_scaling.identical_across_threads([run, other])


def test_a_missing_binary_is_a_clear_error(tmp_path):
    cmd = [sys.executable, "scripts/gpu_checks.py", "scaling", str(tmp_path), "--binary", "nope"]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode != 0
    assert done.stderr.strip().splitlines()[-1].startswith("error: no raster_timing binary")


@pytest.mark.skipif(not BINARY.is_file(), reason="raster_timing example not built")
def test_gpu_checks_scaling_on_one_and_two_threads(tmp_path):
    cmd = [
        sys.executable, "scripts/gpu_checks.py", "scaling", str(tmp_path), "--binary",
        str(BINARY), "--threads", "1,2", "--scenes", "3000@128", "--reps", "2",
    ]  # fmt: skip
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    report = json.loads((tmp_path / "scaling.json").read_text())
    assert [r["threads"] for r in report["runs"]] == [1, 2]
    assert report["identical_across_threads"]
    assert "usable cores" in report["host"]
    md = (tmp_path / "scaling.md").read_text()
    assert "| 3,000 @ 128 | 2 |" in md and "bit-identical across thread counts: yes" in md


def test_rounds_merge_to_the_min_of_mins_and_differing_hashes_are_flagged():
    def one(sort_min: float, image: str) -> dict:
        r = thread_scaling.parse_run(
            SAMPLE.replace("sort ms: min 0.72", f"sort ms: min {sort_min}")
        )
        r["hashes"]["image"] = image
        return {**r, "load": [1.0]}

    merged = thread_scaling.merge([one(0.9, "a"), one(0.7, "a"), one(0.8, "a")])
    assert merged["stages_ms"]["sort"] == [0.7, 0.8]
    assert merged["load"] == [1.0, 1.0, 1.0]
    assert merged["hashes"]["image"] == "a"
    flagged = thread_scaling.merge([one(0.9, "a"), one(0.7, "b")])
    assert flagged["hashes"]["image"] == "differ"
    run = {"scene": "s", **flagged}
    assert not thread_scaling.identical_across_threads([run])
    before = {"scene": "s", "threads": 2, **merged}
    after = {"scene": "s", "threads": 2, **thread_scaling.merge([one(0.35, "a")])}
    assert "| s | sort | 2 | 0.70 / 0.80 | 0.35 / 0.35 | 0.50 |" in thread_scaling.before_after(
        [before], [after]
    )
