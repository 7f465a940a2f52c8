"""``scripts/gpu_checks.py all``: the device checks in one call within a time budget (a
check that does not fit is stopped or left out, and says so), and its dry run on the CPU."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))
import gpu_all  # noqa: E402


def test_checks_that_do_not_fit_the_budget_are_stopped_or_left_out(tmp_path, monkeypatch):
    def sleeper(seconds: float, rc: int = 0) -> list[str]:
        return [sys.executable, "-c", f"import time, sys; time.sleep({seconds}); sys.exit({rc})"]

    plan = [("quick", sleeper(0)), ("failing", sleeper(0, 3)), ("long", sleeper(60)),
            ("late", sleeper(0))]  # fmt: skip
    monkeypatch.setattr(gpu_all, "checks", lambda args, out: plan)
    monkeypatch.setattr(gpu_all, "MIN_CHECK_S", 0.5)
    assert gpu_all.run_all([str(tmp_path), "--budget", "8"]) == 1
    report = json.loads((tmp_path / "all.json").read_text())
    status = {c["name"]: c["status"] for c in report["checks"]}
    assert status == {
        "quick": "passed", "failing": "failed", "long": "stopped: the budget ran out",
        "late": "not run: the budget was spent",
    }  # fmt: skip
    assert report["checks"][1]["rc"] == 3 and report["checks"][2]["seconds"] < 15
    assert report["known_answer_bfloat16_minus_float32_db"] is None  # none was run


def test_every_check_has_a_command_and_the_tiny_plan_stays_on_the_cpu(tmp_path):
    args = gpu_all.argparse.Namespace(tiny=True, baseline=None, work=tmp_path / "work")
    plan = gpu_all.checks(args, tmp_path)
    assert [name for name, _ in plan] == [
        "throughput-16", "known-answer-float32", "known-answer-bfloat16", "vae-precision",
        "throughput-1-32", "resume", "known-answer-render-96",
    ]  # fmt: skip
    for name, cmd in plan:
        assert "cuda" not in cmd, name
        assert "--tiny" in cmd or "--device" in cmd, name


@pytest.mark.slow
def test_the_whole_device_script_as_a_dry_run_on_the_cpu(tmp_path):
    cmd = [sys.executable, "scripts/gpu_checks.py", "all", str(tmp_path), "--tiny",
           "--budget", "1200", "--work", str(tmp_path / "work")]  # fmt: skip
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=1300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    report = json.loads((tmp_path / "all.json").read_text())
    assert [c["status"] for c in report["checks"]] == ["passed"] * 7
    # The known answer in both precisions ran to the end: their gap is a number.
    assert abs(report["known_answer_bfloat16_minus_float32_db"]) < 5.0
    rows = json.loads((tmp_path / "vae_precision.json").read_text())["rows"]
    assert {(r["dtype"], r["format"], r["attention"]) for r in rows} == {
        (d, f, a) for d in ("float32", "bfloat16", "float16")
        for f in ("nchw", "channels_last") for a in ("math", "default")
    }  # fmt: skip
    reference = rows[0]
    assert reference["relative_error"] == 0.0 and reference["cosine"] == pytest.approx(1.0)
    resume = json.loads((tmp_path / "resume" / "throughput.json").read_text())["resume"]
    assert all(resume["identical"].values())
