"""`make demo`: the command it runs (read from `make -n demo`, so the test runs what the
README's command runs), at fewer steps: SDS through the committed known-answer models moves
the plant's noise colours towards its true views, by a margin the known answer supports.

The full demo (200 steps) took bean seed 0 from 11.40 to 17.90 dB. At DEMO_STEPS here it
gains about GAIN_AT_STEPS; the untrained models of the known-answer check lose 0.1 dB in 100
steps (tests/test_known_answer_accuracy.py), so half the gain is a margin no broken SDS
reaches.
"""

from __future__ import annotations

import json
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
STEPS = 50
GAIN_AT_STEPS = 2.2  # dB, measured: 11.40 -> 13.60 in 50 steps
MIN_GAIN_DB = GAIN_AT_STEPS / 2


def demo_command(out: Path, steps: int) -> list[str]:
    """The demo's command line as `make -n demo` prints it, for this Python's environment."""
    venv = Path(sys.executable).parent.parent
    printed = subprocess.run(
        ["make", "-s", "-n", "demo", f"DEMO_OUT={out}", f"DEMO_STEPS={steps}", f"VENV={venv}",
         f"PY={sys.executable}"],
        cwd=ROOT, capture_output=True, text=True, check=True, timeout=60,
    ).stdout  # fmt: skip
    lines = printed.replace("\\\n", " ").splitlines()
    (line,) = [line for line in lines if "known_answer.demo" in line]
    return shlex.split(line)


def test_make_n_demo_shows_sds_generate_on_the_committed_models(tmp_path: Path) -> None:
    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    cmd = demo_command(tmp_path / "demo", 200)
    generate = cmd[cmd.index("--") + 1 :]
    assert Path(generate[0]).name == "plantdreamer" and generate[1] == "generate"
    settings = dict(zip(generate[2::2], generate[3::2], strict=False))
    assert settings["--guidance"] == "sds" and settings["--color-init"] == "noise"
    models = ROOT / "tests/data/known_answer/bean_s0_r64"
    assert (ROOT / settings["--base-model"]).resolve() == models / "base"
    assert (ROOT / settings["--controlnet"]).resolve() == models / "controlnet"
    assert settings["--resolution"] == settings["--sds-resolution"] == "64"
    assert 200 // int(settings["--progress-every"]) >= 4  # several progress pictures


@pytest.mark.slow
def test_the_demo_command_gains_masked_psnr_and_writes_its_figures(tmp_path: Path) -> None:
    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    out = tmp_path / "demo"
    if not (Path(sys.executable).parent / "plantdreamer").is_file():
        pytest.skip("no plantdreamer script beside this Python")
    for steps in (1, STEPS):  # the second run replaces the first one's folder
        cmd = demo_command(out, steps)
        done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
        assert done.returncode == 0, done.stderr[-3000:]
    figures = json.loads((out / "demo.json").read_text())
    print(figures)
    assert figures["steps"] == STEPS and figures["seconds"] > 0
    assert figures["psnr_end"] - figures["psnr_start"] >= MIN_GAIN_DB, figures
    line = done.stdout.strip().splitlines()[-1]
    assert line == (
        f"masked PSNR: {figures['psnr_start']:.2f} dB -> {figures['psnr_end']:.2f} dB "
        f"in {figures['seconds']:.1f} s"
    )
    assert (out / "demo.png").stat().st_size > 0 and (out / "plant.ply").is_file()
    every = int(cmd[cmd.index("--progress-every") + 1])  # the demo's progress pictures
    frames = sorted(p.name for p in (out / "progress").glob("step_*.png"))
    assert frames == [f"step_{s:06d}.png" for s in range(every, STEPS + 1, every)] + (
        [] if STEPS % every == 0 else [f"step_{STEPS:06d}.png"]
    )
