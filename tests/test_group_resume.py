"""A group's resume trusts its plant folders, not a stale record: stopped or killed at any
point (during the export, before the first checkpoint, between two plants' checkpoint
writes, on a full disk), each plant resumes to the bytes of a run never stopped.

The kills run in a subprocess (SIGKILL leaves no handler a chance), the resumes in-process
with the same tiny SDS guidance, so the noise each plant draws is checked too.
"""

import errno
import json
import os
import signal
import subprocess
import sys
import textwrap

import pytest

from plant_runs import done, failed, group, resumed_from
from plantdreamer.pipeline import GenerateConfig, RunInterrupted

SETTINGS = dict(species="mint", steps=6, checkpoint_every=2, points=1500, resolution=48,
                eval_views=2, turntable_frames=2)  # fmt: skip
SEEDS = (0, 1, 2)
NAMES = [f"mint-s{s:04d}" for s in SEEDS]


def tiny_sds():
    from plantdreamer.guidance import StableDiffusionDepthGuidance, tiny_models

    return StableDiffusionDepthGuidance(
        species="mint", components=tiny_models(), resolution=64, seed=0
    )


def configs(**kw):
    return [GenerateConfig.of(seed=s, **{**SETTINGS, **kw}) for s in SEEDS]


def outputs_of(folder):
    """Every file a plant writes, but run.json (it holds timings), by content."""
    return {
        str(p.relative_to(folder)): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name != "run.json"
    }


@pytest.fixture(scope="module")
def straight(tmp_path_factory):
    """The group run never stopped."""
    out = tmp_path_factory.mktemp("straight") / "g"
    result = group(configs(), out, guidance=tiny_sds(), show_progress=False)
    assert sorted(done(result)) == NAMES
    return out


def assert_resumes_to_straight(out, straight):
    result = group(None, out, guidance=tiny_sds(), resume=True, show_progress=False)
    assert sorted(done(result)) == NAMES and not failed(result), failed(result)
    statuses = [p["status"] for p in json.loads((out / "group.json").read_text())["plants"]]
    assert statuses == ["done"] * 3
    for name in NAMES:
        assert outputs_of(out / name) == outputs_of(straight / name), name
        run = json.loads((out / name / "run.json").read_text())
        assert len(run["per_step_s"]) and run["config"]["steps"] == 6
    return result


def killed_in_a_subprocess(out, hook: str) -> None:
    """Runs the group in a fresh process whose ``hook`` (Python, with ``os``, ``signal`` and
    the pipeline's modules at hand) SIGKILLs it; the process must die by SIGKILL. It runs
    torch on this process's thread count: the tiny networks' CPU kernels may round otherwise
    with another count, and the resumes here continue its run."""
    import torch

    script = "\n".join([
        "import os, signal, torch",
        f"torch.set_num_threads({torch.get_num_threads()})",
        "from plantdreamer.pipeline.state import checkpoint",
        "from plantdreamer.pipeline.runs import sequence as run",
        "from plant_runs import group",
        "from test_group_resume import configs, tiny_sds",
        hook,
        f"group(configs(), {str(out)!r}, guidance=tiny_sds(), show_progress=False,"
        "               on_step=globals().get('on_step'))",
    ])  # fmt: skip
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([os.path.dirname(__file__), *sys.path])}
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True,
                          timeout=600)  # fmt: skip
    assert done.returncode == -signal.SIGKILL, done.stderr[-2000:]


@pytest.mark.slow
def test_sigkill_before_the_first_checkpoint_starts_the_plants_again(tmp_path, straight):
    out = tmp_path / "g"
    killed_in_a_subprocess(out, textwrap.dedent("""
        def on_step(step):
            if step == 0:
                os.kill(os.getpid(), signal.SIGKILL)
        """))  # fmt: skip
    record = json.loads((out / "group.json").read_text())["plants"]
    assert [p["status"] for p in record] == ["running"] * 3  # what a kill leaves
    assert not list(out.glob("*/checkpoint*.pt"))
    assert_resumes_to_straight(out, straight)


@pytest.mark.slow
def test_plants_killed_between_two_checkpoint_writes_resume_from_their_common_step(
    tmp_path, straight
):
    out = tmp_path / "g"
    killed_in_a_subprocess(out, textwrap.dedent("""
        write = checkpoint.PlantCheckpoints.write
        def second_plant_dies(self, record):
            if record.step == 4 and self.folder.name == "mint-s0001":
                os.kill(os.getpid(), signal.SIGKILL)
            write(self, record)
        checkpoint.PlantCheckpoints.write = second_plant_dies
        """))  # fmt: skip
    from plantdreamer.pipeline.state.checkpoint import PlantCheckpoints

    # The first plant holds step 4 (and its step 2 kept), the others step 2 only.
    assert sorted(PlantCheckpoints(out / NAMES[0]).starts()) == [2, 4]
    assert sorted(PlantCheckpoints(out / NAMES[1]).starts()) == [2]
    result = assert_resumes_to_straight(out, straight)
    assert resumed_from(result) == dict.fromkeys(NAMES, 2)


@pytest.mark.slow
def test_a_plant_finished_before_a_kill_in_the_export_is_found_finished(tmp_path, straight):
    out = tmp_path / "g"
    killed_in_a_subprocess(out, textwrap.dedent("""
        export = run.export_run
        def killed_after_the_first(*args):
            result = export(*args)
            os.kill(os.getpid(), signal.SIGKILL)
        run.export_run = killed_after_the_first
        """))  # fmt: skip
    record = json.loads((out / "group.json").read_text())["plants"]
    assert [p["status"] for p in record] == ["running"] * 3
    finished = (out / NAMES[0] / "plant.ply").stat().st_mtime_ns
    result = assert_resumes_to_straight(out, straight)
    assert (out / NAMES[0] / "plant.ply").stat().st_mtime_ns == finished  # not made again
    assert resumed_from(result) == {NAMES[1]: 6, NAMES[2]: 6}  # the export only


@pytest.mark.slow
def test_sigterm_during_the_export_stops_between_plants_and_resumes(
    tmp_path, straight, monkeypatch
):
    from plantdreamer.pipeline.runs import sequence as run

    export = run.export_run

    def sigterm_after_the_first(*args):
        result = export(*args)
        os.kill(os.getpid(), signal.SIGTERM)
        return result

    monkeypatch.setattr(run, "export_run", sigterm_after_the_first)
    out = tmp_path / "g"
    with pytest.raises(RunInterrupted) as stop:
        group(configs(), out, guidance=tiny_sds(), show_progress=False)
    assert stop.value.step == 6
    record = json.loads((out / "group.json").read_text())["plants"]
    assert [p["status"] for p in record] == ["done", *["interrupted at step 6"] * 2]
    monkeypatch.setattr(run, "export_run", export)
    assert_resumes_to_straight(out, straight)


@pytest.mark.slow
def test_a_plant_failed_on_a_full_disk_is_tried_again_on_resume(tmp_path, straight, monkeypatch):
    from plantdreamer.pipeline.runs import sequence as run

    export = run.export_run

    def disk_full_for_the_second(cfg, state, folder, *args):
        if folder.name == NAMES[1]:
            raise OSError(errno.ENOSPC, "No space left on device")
        return export(cfg, state, folder, *args)

    monkeypatch.setattr(run, "export_run", disk_full_for_the_second)
    out = tmp_path / "g"
    first = group(configs(), out, guidance=tiny_sds(), show_progress=False)
    assert sorted(done(first)) == [NAMES[0], NAMES[2]]
    assert "No space left" in failed(first)[NAMES[1]]
    monkeypatch.setattr(run, "export_run", export)
    assert_resumes_to_straight(out, straight)
