"""A SIGTERM (a scheduler's notice, ``timeout``, ``kill``) that arrives while ``generate``
exports its views stops it within one view: the final checkpoint is already written, so
``--resume`` redoes the export, and the plant is the one an unbroken run makes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from plantdreamer.pipeline import GenerateConfig, RunInterrupted, generate_plants
from plantdreamer.pipeline.model.gaussian_model import GaussianModel
from plantdreamer.pipeline.state.checkpoint import CHECKPOINT_NAME

SETTINGS = dict(species="bean", guidance="none", points=300, steps=0, eval_views=8,
                resolution=16, turntable="none", seed=2)  # fmt: skip


def test_sigterm_during_the_export_stops_it_and_resume_redoes_it(tmp_path, monkeypatch):
    rendered = GaussianModel.render
    calls = []

    def render_then_signal(self, *args, **kwargs):  # the notice comes as view 2 renders
        calls.append(1)
        if len(calls) == 3:
            os.kill(os.getpid(), signal.SIGTERM)
        return rendered(self, *args, **kwargs)

    monkeypatch.setattr(GaussianModel, "render", render_then_signal)
    out = tmp_path / "stopped"
    with pytest.raises(RunInterrupted):
        generate_plants([GenerateConfig.of(**SETTINGS)], out, show_progress=False)
    monkeypatch.undo()
    assert len(calls) == 3  # stopped within one view: nothing rendered after the notice
    assert 0 < len(list((out / "renders").glob("view_*.png"))) < 8
    assert (out / CHECKPOINT_NAME).is_file() and not (out / "run.json").exists()
    first = (out / "renders" / "view_000.png").read_bytes()
    generate_plants(None, out, resume=True, show_progress=False)  # the export again, whole
    assert len(list((out / "renders").glob("view_*.png"))) == 8 and (out / "run.json").is_file()
    assert (out / "renders" / "view_000.png").read_bytes() == first  # the same model's view
    assert not (out / CHECKPOINT_NAME).exists()


@pytest.mark.slow
def test_a_sigterm_stops_a_long_export_within_seconds(tmp_path):
    """A real process and signal: an export of 3600 views, stopped after a few."""
    out = tmp_path / "run"
    args = [sys.executable, "-m", "plantdreamer", "generate", "--species", "bean", "--guidance",
            "none", "--points", "300", "--steps", "0", "--eval-views", "3600", "--resolution",
            "32", "--turntable", "none", "--quiet", "--out", str(out)]  # fmt: skip
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.time() + 120
        while len(list((out / "renders").glob("view_*.png"))) < 5:
            assert proc.poll() is None and time.time() < deadline, "the export never started"
            time.sleep(0.05)
        sent = time.time()
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=30)
        stopped_in = time.time() - sent
    finally:
        proc.kill()
    assert proc.returncode == 130, stderr
    assert stopped_in < 10, stopped_in
    assert "--resume" in stderr and (out / CHECKPOINT_NAME).is_file()
    assert len(list((out / "renders").glob("view_*.png"))) < 3600
