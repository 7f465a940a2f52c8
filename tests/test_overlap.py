"""A group trained as two halves in flight (``overlap on``): the schedule (one half's host
work beside the other's guidance, drained before checkpoints), complete folders, both halves
trained, the same bytes run to run and after Ctrl-C + resume, a failing plant alone."""

import json

import pytest
import torch

from plant_runs import done, failed, group
from plantdreamer.pipeline import GenerateConfig, RunInterrupted
from plantdreamer.pipeline.settings.runtime import resolve_overlap
from plantdreamer.pipeline.step.schedule import StepSchedule
from test_group import SMALL, _stop_at, outputs_of, tiny_sds

NAMES = [f"mint-s{s:04d}" for s in range(4)]


def four(steps, overlap="on", **more):
    return [
        GenerateConfig.of(species="mint", seed=s, steps=steps, overlap=overlap, **SMALL, **more)
        for s in range(4)
    ]


class _HalvesGuidance:
    """Mean squared error to per-plant targets, for a group of four in two halves called
    in turn (plants 0-1, then 2-3)."""

    needs_depth, resolution, generator = False, None, None

    def __init__(self, targets):
        self.targets, self.calls = targets, 0

    def __call__(self, images, depth_cond, cameras, step):
        from plantdreamer.guidance.base import GuidanceOutput

        half = self.targets[2 * (self.calls % 2) :][: images.shape[0]]
        self.calls += 1
        loss = torch.mean((images - half) ** 2)
        return GuidanceOutput(loss=loss, stats={"loss": float(loss.detach())})


def test_auto_overlaps_only_a_group_whose_guidance_runs_on_cuda():
    cuda, cpu = True, False  # whether the group's guidance runs on CUDA
    assert resolve_overlap("auto", cuda, 4) and resolve_overlap("auto", cuda, 2)
    assert not resolve_overlap("auto", cuda, 1) and not resolve_overlap("auto", cpu, 4)
    assert resolve_overlap("on", cpu, 4) and not resolve_overlap("off", cuda, 4)


def test_one_half_is_launched_while_the_other_finishes_and_drains_at_checkpoints(
    tmp_path, monkeypatch
):
    """Launch = render + guidance queued; finish = wait, rasterizer backward, Adam."""
    order = []
    launch, finish = StepSchedule._launch, StepSchedule._finish

    def spy_launch(self, plants, step, more):
        order.append(("launch", step, "AB"[plants[0] >= 2]))
        return launch(self, plants, step, more)

    def spy_finish(self, work, step):
        order.append(("finish", step, "AB"[work.plants[0] >= 2]))
        return finish(self, work, step)

    monkeypatch.setattr(StepSchedule, "_launch", spy_launch)
    monkeypatch.setattr(StepSchedule, "_finish", spy_finish)
    guidance = _HalvesGuidance(torch.full((4, 48, 48, 3), 0.5))
    group(four(4, checkpoint_every=2, turntable="none"), tmp_path / "g",
                   guidance=guidance, show_progress=False)  # fmt: skip
    expected = [
        ("launch", 0, "A"), ("launch", 0, "B"), ("finish", 0, "A"),
        ("launch", 1, "A"),  # A's next step during B's networks
        ("finish", 0, "B"), ("launch", 1, "B"), ("finish", 1, "A"),
        ("finish", 1, "B"),  # a checkpoint at step 2: nothing in flight
        ("launch", 2, "A"), ("launch", 2, "B"), ("finish", 2, "A"),
        ("launch", 3, "A"), ("finish", 2, "B"), ("launch", 3, "B"),
        ("finish", 3, "A"), ("finish", 3, "B"),  # the last step: nothing ahead
    ]  # fmt: skip
    assert order == expected


@pytest.mark.slow
def test_an_overlapped_group_of_four_writes_complete_folders_and_trains_both_halves(tmp_path):
    untrained = group(four(0), tmp_path / "u", guidance=tiny_sds(), show_progress=False)
    result = group(four(3), tmp_path / "g", guidance=tiny_sds(), show_progress=False)
    assert sorted(done(result)) == sorted(done(untrained)) == NAMES and not failed(result)
    for name in NAMES:
        folder = tmp_path / "g" / name
        run = json.loads((folder / "run.json").read_text())
        assert run["config"]["overlap"] == "on" and run["labels"]["exported"]
        for entry in ("plant.ply", "transforms.json", "turntable.gif"):
            assert (folder / entry).is_file(), (name, entry)
        for views in ("renders", "labels", "instances", "depth"):
            assert len(list((folder / views).glob("view_*.png"))) == 2, (name, views)
        # Every plant of both halves took its three Adam steps.
        assert len((folder / "log.csv").read_text().splitlines()) == 1 + 3, name
        before = (tmp_path / "u" / name / "plant.ply").read_bytes()
        assert (folder / "plant.ply").read_bytes() != before, name
    # Each plant logs its own sample's timestep; a half's two draws average to its logged
    # batch mean, so every draw went to the plant it was drawn for.
    for half in (NAMES[:2], NAMES[2:]):
        logs = [_log_rows(tmp_path / "g" / name / "log.csv") for name in half]
        for first, second in zip(*logs, strict=True):
            own = [float(first["timesteps"]), float(second["timesteps"])]
            assert first["timestep"] == second["timestep"] == str(sum(own) / 2)
            assert all(float(r["t_min"]) <= t <= float(r["t_max"]) for r in (first, second)
                       for t in own)  # fmt: skip


def _log_rows(path):
    import csv

    with path.open(newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_an_overlapped_group_is_byte_identical_run_to_run_and_after_ctrl_c_and_resume(tmp_path):
    cfgs = four(6, checkpoint_every=4)
    first = group(cfgs, tmp_path / "a", guidance=tiny_sds(), show_progress=False)
    group(cfgs, tmp_path / "b", guidance=tiny_sds(), show_progress=False)
    # Ctrl-C after step 1, while step 2's first half is in flight: the stop waits a step.
    with pytest.raises(RunInterrupted) as stop:
        group(cfgs, tmp_path / "c", guidance=tiny_sds(), show_progress=False,
                       on_step=_stop_at(1))  # fmt: skip
    assert stop.value.step == 3
    resumed = group(None, tmp_path / "c", guidance=tiny_sds(), resume=True,
                             show_progress=False)  # fmt: skip
    assert sorted(done(first)) == sorted(done(resumed)) == NAMES
    for name in NAMES:
        a = outputs_of(tmp_path / "a" / name)
        assert a == outputs_of(tmp_path / "b" / name), name
        assert a == outputs_of(tmp_path / "c" / name), name


def test_a_plant_whose_training_goes_non_finite_fails_alone_in_an_overlapped_group(tmp_path):
    targets = torch.full((4, 48, 48, 3), 0.5)
    targets[1] = float("nan")  # the first half's second plant
    result = group(four(1, turntable="none"), tmp_path / "g",
                            guidance=_HalvesGuidance(targets),
                            show_progress=False)  # fmt: skip
    assert sorted(done(result)) == [NAMES[0], NAMES[2], NAMES[3]]
    assert list(failed(result)) == [NAMES[1]]
    assert not (tmp_path / "g" / NAMES[1] / "plant.ply").exists()


def test_an_sds_launch_leaves_its_figures_on_the_device_until_read_back():
    """``launch`` reads nothing back (a read would make the host wait for the GPU); the
    figures read back later are the plain call's, with the same draws."""
    from plantdreamer.cameras import orbit
    from plantdreamer.guidance import StableDiffusionDepthGuidance, tiny_models

    def run(launch):
        guidance = StableDiffusionDepthGuidance(components=tiny_models(), resolution=64, seed=0)
        images = torch.full((2, 64, 64, 3), 0.75)
        depth = torch.rand(2, 1, 64, 64, generator=torch.Generator().manual_seed(0))
        cameras = [orbit(4.0, 15.0, a, 50.0, 64, 64) for a in (0.0, 90.0)]
        if launch:
            pending = guidance.launch(images, depth, cameras, 0)
            on_device = {k for k, v in pending.stats.items() if isinstance(v, torch.Tensor)}
            assert on_device == {"loss", "grad_norm", "timestep", "timesteps", "nonfinite_grad"}
            return pending.result()
        return guidance(images, depth, cameras, 0)

    launched, called = run(True), run(False)
    assert list(launched.stats) == list(called.stats)  # log.csv's column order
    assert launched.stats == called.stats and torch.equal(launched.loss, called.loss)
