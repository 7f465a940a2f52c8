"""One run of N plants from the entry to the record (``pipeline/runs/``): one entry for a plant
alone, a group and a dataset unit, the record and resume rule they share, the failure policy
as a parameter, the group's noise saved once, the settings resolved once (what
``--print-config`` prints is what run.json records), and the trainer's observers."""

from __future__ import annotations

import json
import signal

import pytest
import torch
from click.testing import CliRunner

from plantdreamer.cli import main
from plantdreamer.errors import InputError
from plantdreamer.pipeline import (
    FolderPerPlant,
    GenerateConfig,
    GivenFolders,
    PlantAlone,
    RunInterrupted,
    generate_plants,
)
from plantdreamer.pipeline.observer import TrainerObserver

TINY = dict(points=300, resolution=24, eval_views=1, turntable="none", guidance="none")
CLI_TINY = ["--species", "bean", "--points", "300", "--eval-views", "1", "--turntable", "none",
            "--guidance", "none", "--steps", "0", "--quiet"]  # fmt: skip


def tiny(**kw):
    return GenerateConfig.of(**{"species": "bean", "steps": 2, **TINY, **kw})


def photometric():
    from plantdreamer.guidance.base import PhotometricGuidance

    return PhotometricGuidance(torch.full((1, 24, 24, 3), 0.4))


def tiny_sds():
    from plantdreamer.guidance import StableDiffusionDepthGuidance, tiny_models

    return StableDiffusionDepthGuidance(components=tiny_models(), resolution=16, seed=0)


@pytest.mark.parametrize("seeds", [None, "0,1"])
def test_print_config_is_the_config_run_json_records(tmp_path, seeds):
    """Every setting left auto (resolution, precision, template, overlap) is decided by the
    one function ``--print-config`` calls: the config it prints is run.json's, byte for
    byte, for a plant alone and for each plant of a group."""
    args = [*CLI_TINY, *(["--seeds", seeds] if seeds else [])]
    shown = CliRunner().invoke(main, ["generate", *args, "--print-config"])
    assert shown.exit_code == 0, shown.output
    printed = [plant["config"] for plant in json.loads(shown.output)]
    assert printed[0]["resolution"] is not None and printed[0]["overlap"] in ("on", "off")
    assert printed[0]["network-dtype"] != "auto" and printed[0]["prompt-template"] is not None
    out = tmp_path / "run"
    made = CliRunner().invoke(main, ["generate", *args, "--out", str(out)])
    assert made.exit_code == 0, made.output
    folders = [out] if seeds is None else [out / f"bean-s000{s}" for s in (0, 1)]
    recorded = [json.loads((f / "run.json").read_text())["config"] for f in folders]
    assert [json.dumps(c) for c in printed] == [json.dumps(c) for c in recorded]
    run = json.loads((folders[0] / "run.json").read_text())
    assert "seed" not in run and "eval_distance" not in run  # recorded once, in their place
    assert run["outputs"]["eval_distance"] > 0  # the orbit framed on the plant


def test_a_plant_alone_resumes_by_the_record_and_rule_of_a_group(tmp_path):
    """A finished plant alone is found done by its folder, as a group's plant is; resuming
    a folder that holds no run is one error."""
    first = generate_plants([tiny()], tmp_path / "a", show_progress=False)[0]
    again = generate_plants(None, tmp_path / "a", resume=True, show_progress=False)[0]
    assert again.done and again.gaussians == first.gaussians and again.resumed_from is None
    with pytest.raises(Exception, match="no checkpoint to resume from"):
        generate_plants(None, tmp_path / "empty", resume=True, show_progress=False)
    with pytest.raises(InputError, match="one config"):
        generate_plants([tiny(), tiny(seed=1)], tmp_path / "b", show_progress=False)


def test_the_failure_policy_is_a_parameter_not_the_layout(tmp_path):
    """A plant whose input cannot work raises under ``raise`` and is recorded under
    ``record``, in a folder per plant alike."""
    cfgs = [tiny(pointcloud=str(tmp_path / "missing.ply")), tiny(seed=1)]
    with pytest.raises(Exception, match=r"missing\.ply"):
        generate_plants(cfgs, tmp_path / "r", layout=FolderPerPlant(), show_progress=False)
    assert not (tmp_path / "r").exists()  # refused before anything was claimed
    results = generate_plants(cfgs, tmp_path / "g", layout=FolderPerPlant(), failures="record",
                              show_progress=False)  # fmt: skip
    assert [r.status for r in results] == ["failed", "done"] and "missing.ply" in results[0].error
    with pytest.raises(InputError, match="failures must be one of"):
        generate_plants(cfgs, tmp_path / "x", failures="ignore", show_progress=False)


def test_a_groups_noise_is_saved_once_beside_its_plants_checkpoints(tmp_path):
    """A stopped group holds one noise state (``noise.pt``, in the group's folder) at the
    checkpoints' step; the plants' checkpoints hold none (format 5), and the file goes once
    the plants have trained to the end."""
    cfgs = [tiny(seed=s, steps=6, checkpoint_every=2) for s in (0, 1)]

    def stop_at_3(step):
        if step == 3:
            signal.raise_signal(signal.SIGINT)

    with pytest.raises(RunInterrupted) as stop:
        generate_plants(cfgs, tmp_path / "g", layout=FolderPerPlant(), failures="record",
                        guidance=tiny_sds(), on_step=stop_at_3, show_progress=False)  # fmt: skip
    assert stop.value.step == 4 and [r.status for r in stop.value.results] == ["interrupted"] * 2
    noise = torch.load(tmp_path / "g" / "noise.pt", weights_only=True)
    (trainer,) = noise["trainers"]
    assert trainer["plants"] == ["bean-s0000", "bean-s0001"] and list(trainer["steps"]) == ["4"]
    for name in trainer["plants"]:
        saved = torch.load(tmp_path / "g" / name / "checkpoint.pt", weights_only=True)
        assert saved["format"] == 5 and "guidance" not in saved and saved["step"] == 4
        assert not (tmp_path / "g" / name / "noise.pt").exists()
    results = generate_plants(None, tmp_path / "g", layout=FolderPerPlant(), failures="record",
                              resume=True, guidance=tiny_sds(), show_progress=False)  # fmt: skip
    assert [r.resumed_from for r in results] == [4, 4] and all(r.done for r in results)
    assert not (tmp_path / "g" / "noise.pt").exists()


def test_a_dataset_unit_writes_its_plant_folders_and_nothing_beside(tmp_path):
    """Given folders (a dataset unit): the plants are written there, named by them; the
    record is the caller's (no group.json, no folder for the group)."""
    folders = (tmp_path / "plants" / "p0", tmp_path / "plants" / "p1")
    results = generate_plants([tiny(), tiny(seed=1)], tmp_path / "plants",
                              layout=GivenFolders(folders), failures="record", resume=True,
                              show_progress=False)  # fmt: skip
    assert [r.name for r in results] == ["p0", "p1"] and all(r.done for r in results)
    assert sorted(p.name for p in (tmp_path / "plants").iterdir()) == ["p0", "p1"]
    assert [r.trained_with for r in results] == [("p0", "p1")] * 2
    again = generate_plants([tiny(), tiny(seed=1)], tmp_path / "plants",
                            layout=GivenFolders(folders), failures="record", resume=True,
                            show_progress=False)  # fmt: skip
    assert all(r.done and r.trained_with == () for r in again)  # found done: not retrained


def test_observers_hear_the_phases_the_steps_and_each_checkpoint_before_it_is_written(
    tmp_path,
):
    events = []

    class Watch(TrainerObserver):
        def phase_end(self, phase, seconds):
            events.append(("phase", phase))

        def step_end(self, step, plants, loss):
            events.append(("step", step, loss is not None))

        def checkpoint(self, step, plants):
            on_disk = (plants[0].out_dir / "checkpoint.pt").is_file()
            events.append(("checkpoint", step, on_disk))

    generate_plants([tiny(steps=4, checkpoint_every=2)], tmp_path / "a", guidance=photometric(),
                    observers=[Watch()], show_progress=False)  # fmt: skip
    steps = [e for e in events if e[0] == "step"]
    assert steps == [("step", s, True) for s in range(4)]
    assert [e for e in events if e[0] == "checkpoint"] == [("checkpoint", 2, False),
                                                           ("checkpoint", 4, True)]  # fmt: skip
    phases = {e[1] for e in events if e[0] == "phase"}
    assert {"raster.forward", "guidance.launch", "raster.backward", "optimizer"} <= phases
    # Each step's phases come before its end.
    first_end = events.index(("step", 0, True))
    assert ("phase", "optimizer") in events[:first_end]


def test_layouts_are_found_by_their_record(tmp_path):
    from plantdreamer.pipeline.runs.layout import found_layout

    generate_plants([tiny(seed=s) for s in (0, 1)], tmp_path / "g", layout=FolderPerPlant(),
                    failures="record", show_progress=False)  # fmt: skip
    assert found_layout(tmp_path / "g") == FolderPerPlant()
    assert found_layout(tmp_path / "g" / "bean-s0000") == PlantAlone()


class _Killed(BaseException):
    """A kill, in-process: nothing after it runs but the finally blocks."""


def test_a_kill_right_after_a_checkpoint_leaves_no_picture_missing_on_resume(tmp_path, monkeypatch):
    """The progress pictures of a step are written before its checkpoint: a run killed just
    after writing the checkpoint at step 4 resumes there with step 4's picture on disk, and
    ends with the unbroken run's pictures."""
    from plantdreamer.pipeline.state import checkpoint

    cfg = tiny(steps=6, checkpoint_every=2)
    generate_plants([cfg], tmp_path / "full", guidance=photometric(), show_progress=False)
    write = checkpoint.PlantCheckpoints.write

    def killed_after_step_4(self, record):
        write(self, record)
        if record.step == 4:
            raise _Killed

    monkeypatch.setattr(checkpoint.PlantCheckpoints, "write", killed_after_step_4)
    with pytest.raises(_Killed):
        generate_plants([cfg], tmp_path / "cut", guidance=photometric(), show_progress=False)
    monkeypatch.setattr(checkpoint.PlantCheckpoints, "write", write)
    assert (tmp_path / "cut" / "progress" / "step_000004.png").is_file()
    resumed = generate_plants(None, tmp_path / "cut", guidance=photometric(), resume=True,
                              show_progress=False)[0]  # fmt: skip
    assert resumed.resumed_from == 4
    for name in ("progress.png", *(f"progress/step_00000{s}.png" for s in (2, 4, 6))):
        assert (tmp_path / "cut" / name).read_bytes() == (tmp_path / "full" / name).read_bytes()
