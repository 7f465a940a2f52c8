"""Several plants in one trainer (`generate --seeds`): complete folders, deterministic
bytes run to run and after Ctrl-C + resume, a bad plant failing alone."""

import json
import os
import signal

import numpy as np
import pytest
from click.testing import CliRunner

from plant_runs import done, failed, group
from plantdreamer.cli import main
from plantdreamer.cloud import PointCloud
from plantdreamer.pipeline import GenerateConfig, RunInterrupted, generate_plants
from plantdreamer.pipeline.settings.group_settings import parse_group_seeds as parse_seeds

SMALL = dict(points=1500, resolution=48, eval_views=2, turntable_frames=2)


def tiny_sds(seed=0):
    from plantdreamer.guidance import StableDiffusionDepthGuidance, tiny_models

    return StableDiffusionDepthGuidance(
        species="mint", components=tiny_models(), resolution=64, seed=seed
    )


def outputs_of(folder):
    """Every file a plant writes, but run.json (it holds timings), by content."""
    return {
        str(p.relative_to(folder)): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name not in ("run.json", "group.json")
    }


def test_seeds_are_ranges_and_lists():
    assert parse_seeds("0-3,8") == [0, 1, 2, 3, 8] and parse_seeds("5,1") == [5, 1]
    from plantdreamer.errors import InputError

    for bad in ("", "1,1", "a-b"):
        with pytest.raises(InputError):
            parse_seeds(bad)


def test_a_group_of_three_writes_three_complete_plant_folders(tmp_path):
    out = tmp_path / "g"
    args = ["generate", "--species", "bean", "--seeds", "0,3,5", "--guidance", "none",
            "--points", "1500", "--resolution", "32", "--eval-views", "2", "--steps", "0",
            "--turntable-frames", "2", "--out", str(out), "--quiet"]  # fmt: skip
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    names = ["bean-s0000", "bean-s0003", "bean-s0005"]
    status = json.loads((out / "group.json").read_text())["plants"]
    assert [(p["name"], p["status"]) for p in status] == [(n, "done") for n in names]
    for name in names:
        folder = out / name
        run = json.loads((folder / "run.json").read_text())
        assert run["config"]["seed"] == int(name[-4:]) and run["labels"]["exported"]
        for entry in ("plant.ply", "transforms.json", "turntable.gif"):
            assert (folder / entry).is_file(), (name, entry)
        for views in ("renders", "labels", "instances", "depth"):
            assert len(list((folder / views).glob("view_*.png"))) == 2, (name, views)
        assert not (folder / "checkpoint.pt").exists()
    # Different seeds, different plants.
    assert (out / names[0] / "plant.ply").read_bytes() != (
        out / names[1] / "plant.ply"
    ).read_bytes()


def _stop_at(step_to_stop):
    def hook(step):
        if step == step_to_stop:
            os.kill(os.getpid(), signal.SIGINT)

    return hook


@pytest.mark.slow
def test_a_group_is_byte_identical_run_to_run_and_after_ctrl_c_and_resume(tmp_path):
    cfgs = [GenerateConfig.of(species="mint", seed=s, steps=6, checkpoint_every=4, **SMALL)
            for s in (0, 1, 2)]  # fmt: skip
    first = group(cfgs, tmp_path / "a", guidance=tiny_sds(), show_progress=False)
    group(cfgs, tmp_path / "b", guidance=tiny_sds(), show_progress=False)
    assert sorted(done(first)) == ["mint-s0000", "mint-s0001", "mint-s0002"] and not failed(first)
    with pytest.raises(RunInterrupted) as stop:
        group(cfgs, tmp_path / "c", guidance=tiny_sds(), show_progress=False,
                       on_step=_stop_at(2))  # fmt: skip
    assert stop.value.step == 3
    assert not list((tmp_path / "c").glob("*/plant.ply"))
    resumed = group(None, tmp_path / "c", guidance=tiny_sds(), resume=True,
                             show_progress=False)  # fmt: skip
    assert sorted(done(resumed)) == sorted(done(first))
    for name in done(first):
        a = outputs_of(tmp_path / "a" / name)
        assert a == outputs_of(tmp_path / "b" / name), name
        assert a == outputs_of(tmp_path / "c" / name), name
    plys = {(tmp_path / "a" / n / "plant.ply").read_bytes() for n in done(first)}
    assert len(plys) == 3


def test_a_group_of_one_is_the_plant_made_alone(tmp_path):
    cfg = GenerateConfig.of(species="mint", seed=4, steps=3, **SMALL)
    alone = generate_plants([cfg], tmp_path / "alone", guidance=tiny_sds(4), show_progress=False)[0]
    together = group([cfg], tmp_path / "g", guidance=tiny_sds(4), show_progress=False)
    assert done(together)["mint-s0004"].ply_path.read_bytes() == alone.ply_path.read_bytes()


def test_a_bad_point_cloud_fails_alone(tmp_path):
    from plantdreamer.io import write_ply

    rng = np.random.default_rng(0)
    for name in ("a", "c"):
        pts = rng.normal(size=(3000, 3)).astype(np.float32)
        write_ply(
            tmp_path / f"{name}.ply", PointCloud(pts, colors=rng.random((3000, 3), np.float32))
        )
    (tmp_path / "b.ply").write_bytes(b"ply\nformat nonsense\n")
    cfgs = [GenerateConfig.of(species="mint", pointcloud=str(tmp_path / f"{n}.ply"), steps=2,
                              guidance="none", **SMALL) for n in "abc"]  # fmt: skip
    result = group(cfgs, tmp_path / "g", show_progress=False)
    assert sorted(done(result)) == ["a-s0000", "c-s0000"]
    assert list(failed(result)) == ["b-s0000"] and "PlyError" in failed(result)["b-s0000"]
    status = {
        p["name"]: p["status"]
        for p in json.loads((tmp_path / "g" / "group.json").read_text())["plants"]
    }
    assert status["b-s0000"].startswith("failed: ") and status["a-s0000"] == "done"
    assert (tmp_path / "g" / "c-s0000" / "plant.ply").is_file()


def test_plants_of_a_group_must_share_their_settings(tmp_path):
    from plantdreamer.errors import InputError

    cfgs = [
        GenerateConfig.of(species="mint", seed=0),
        GenerateConfig.of(species="mint", seed=1, steps=5),
    ]
    with pytest.raises(InputError, match="these differ: steps"):
        group(cfgs, tmp_path / "g", show_progress=False)


def test_a_plant_whose_training_goes_non_finite_fails_alone(tmp_path):
    import torch

    from plantdreamer.guidance.base import PhotometricGuidance

    targets = torch.full((3, 48, 48, 3), 0.5)
    targets[1] = float("nan")  # the second plant's loss and gradients become NaN
    cfgs = [GenerateConfig.of(species="mint", seed=s, steps=1, **SMALL) for s in (0, 1, 2)]
    result = group(cfgs, tmp_path / "g", guidance=PhotometricGuidance(targets),
                            show_progress=False)  # fmt: skip
    assert sorted(done(result)) == ["mint-s0000", "mint-s0002"]
    assert (
        "non-finite" in failed(result)["mint-s0001"]
        or "loss became" in failed(result)["mint-s0001"]
    )
    assert not (tmp_path / "g" / "mint-s0001" / "plant.ply").exists()
    assert (tmp_path / "g" / "mint-s0002" / "plant.ply").is_file()


def test_a_plant_failed_before_ctrl_c_is_tried_again_on_resume(tmp_path):
    import torch

    from plantdreamer.guidance.base import PhotometricGuidance

    class SecondOfThreeFails(PhotometricGuidance):
        def __call__(self, images, depth_cond, cameras, step):
            self.targets = torch.full_like(images.detach(), 0.5)
            if len(images) == 3:  # the second plant's gradients become NaN
                self.targets[1] = float("nan")
            return super().__call__(images, depth_cond, cameras, step)

    cfgs = [GenerateConfig.of(species="mint", seed=s, steps=6, checkpoint_every=4, **SMALL)
            for s in (0, 1, 2)]  # fmt: skip
    guidance = SecondOfThreeFails(torch.zeros(1, 48, 48, 3))
    with pytest.raises(RunInterrupted):
        group(cfgs, tmp_path / "g", guidance=guidance, show_progress=False,
                       on_step=_stop_at(2))  # fmt: skip
    record = json.loads((tmp_path / "g" / "group.json").read_text())["plants"]
    status = {p["name"]: p["status"] for p in record}
    assert status["mint-s0001"].startswith("failed: ")  # written on the way out
    # Stopped, not still "running" (the record says where the others stopped).
    assert status["mint-s0000"] == status["mint-s0002"] == "interrupted at step 3"
    # The resume tries it again (alone, from step 0: it failed before any checkpoint, and
    # the guidance fails only the second of three).
    resumed = group(None, tmp_path / "g", guidance=guidance, resume=True,
                             show_progress=False)  # fmt: skip
    assert [r.name for r in resumed if r.retried] == ["mint-s0001"] and not failed(resumed)
    assert sorted(done(resumed)) == ["mint-s0000", "mint-s0001", "mint-s0002"]
    assert (tmp_path / "g" / "mint-s0001" / "plant.ply").is_file()


# --- the command line: one path for one plant or a group ------------------------------------

TINY = ["--species", "bean", "--guidance", "none", "--points", "500", "--resolution", "32",
        "--eval-views", "1", "--turntable-frames", "1", "--turntable", "none"]  # fmt: skip


def _one_error(result, message):
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert result.exit_code == 1 and len(errors) == 1, result.output
    assert "Traceback" not in result.output and message in errors[0], result.output
    return errors[0]


def test_print_config_of_a_group_prints_every_plant_and_trains_nothing(tmp_path):
    out = tmp_path / "g"
    result = CliRunner().invoke(
        main, ["generate", "--species", "bean", "--seeds", "0-2", "--print-config", "--out", out]
    )
    assert result.exit_code == 0, result.output
    shown = json.loads(result.output)
    assert [plant["config"]["seed"] for plant in shown] == [0, 1, 2]
    assert not out.exists()


def test_view_shows_every_plant_of_a_group(tmp_path, monkeypatch):
    viewed = []
    monkeypatch.setattr(
        "plantdreamer.viewer.server.view_files", lambda paths, **kw: viewed.append(paths)
    )
    out = tmp_path / "g"
    args = ["generate", *TINY, "--steps", "0", "--seeds", "0,3", "--view", "--quiet", "--out", out]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    assert viewed == [
        [str(out / "bean-s0000" / "plant.ply"), str(out / "bean-s0003" / "plant.ply")]
    ]


def test_a_group_is_viewed_side_by_side():
    from plantdreamer.viewer.scene import SplatScene, side_by_side

    def scene(x0, n):
        centers = np.zeros((n, 3), np.float32)
        centers[:, 0] = np.linspace(x0, x0 + 1.0, n)
        return SplatScene("p", centers, np.zeros((n, 3, 3), np.float32),
                          np.zeros((n, 3), np.float32), np.ones((n, 1), np.float32),
                          np.arange(n, dtype=np.int32))  # fmt: skip

    row = side_by_side([scene(5.0, 3), scene(-2.0, 4)])
    assert len(row) == 7 and row.labels is not None and len(row.labels) == 7
    first, second = row.centers[:3, 0], row.centers[3:, 0]
    assert first.max() < second.min()  # in order, apart
    np.testing.assert_allclose(second.min() - first.max(), 0.1, rtol=1e-5)  # a tenth of the widest


def test_seeds_beyond_what_one_trainer_holds_are_refused_before_anything_runs(tmp_path):
    for seeds in ("0-9999", "0-20000000"):
        out = tmp_path / seeds
        result = CliRunner().invoke(main, ["generate", *TINY, "--seeds", seeds, "--out", out])
        _one_error(result, "at most 64")
        assert not out.exists()


def _interrupted(out, seeds=None):
    """A run (``seeds``: a group) stopped by Ctrl-C at step 2 of 4, with checkpoints."""
    cfgs = [GenerateConfig.of(species="bean", guidance="none", steps=4, checkpoint_every=2,
                              points=500, resolution=32, eval_views=1, turntable_frames=1,
                              seed=s) for s in (seeds or [5])]  # fmt: skip
    with pytest.raises(RunInterrupted):
        if seeds is None:
            generate_plants([cfgs[0]], out, show_progress=False, on_step=_stop_at(1))
        else:
            group(cfgs, out, show_progress=False, on_step=_stop_at(1))


def test_a_resume_says_where_it_resumes_for_a_plant_and_a_group(tmp_path):
    _interrupted(tmp_path / "plant")
    _interrupted(tmp_path / "group", seeds=[0, 1])
    for name in ("plant", "group"):
        result = CliRunner().invoke(main, ["generate", "--resume", tmp_path / name])
        assert result.exit_code == 0, result.output
        said = [line for line in result.output.splitlines() if line.startswith("resuming")]
        assert said == ["resuming at step 2"], (name, result.output)


def test_a_damaged_checkpoint_is_the_same_one_line_in_a_group(tmp_path):
    import torch

    _interrupted(tmp_path / "plant")
    _interrupted(tmp_path / "group", seeds=[0, 1])
    paths = [
        tmp_path / "plant" / "checkpoint.pt",
        tmp_path / "group" / "bean-s0001" / "checkpoint.pt",
    ]
    for path in paths:
        state = torch.load(path, weights_only=True)
        del state["model"]
        torch.save(state, path)
    alone = _one_error(CliRunner().invoke(main, ["generate", "--resume", tmp_path / "plant"]),
                       "damaged or incompatible checkpoint")  # fmt: skip
    in_group = _one_error(CliRunner().invoke(main, ["generate", "--resume", tmp_path / "group"]),
                          "1 of 2 plants failed")  # fmt: skip
    message = alone.removeprefix("error: ").replace(str(paths[0]), str(paths[1]))
    assert f"bean-s0001: CheckpointError: {message}" in in_group


@pytest.mark.parametrize(
    "hostile",
    [{"name": "../escaped"}, {"name": "/tmp/escaped"}, {"dir": "ELSEWHERE"}, "link"],
    ids=["dotdot-name", "absolute-name", "absolute-dir", "linked-folder"],
)
def test_a_group_record_never_leads_a_resume_out_of_its_folder(tmp_path, hostile):
    out = tmp_path / "group"
    _interrupted(out, seeds=[0, 1])
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    record = json.loads((out / "group.json").read_text())
    if hostile == "link":  # the second plant's folder is a link to a folder outside
        (out / "bean-s0001").rename(elsewhere / "bean-s0001")
        (out / "bean-s0001").symlink_to(elsewhere / "bean-s0001")
    else:
        given = {k: str(elsewhere) if v == "ELSEWHERE" else v for k, v in hostile.items()}
        record["plants"][1].update(given)
        (out / "group.json").write_text(json.dumps(record))
    before = {p: p.stat().st_mtime_ns for p in tmp_path.rglob("*") if not p.is_symlink()}
    result = CliRunner().invoke(main, ["generate", "--resume", out, "--quiet"])
    _one_error(result, "group.json")
    after = {p: p.stat().st_mtime_ns for p in tmp_path.rglob("*") if not p.is_symlink()}
    assert after == before  # nothing made, removed or changed, inside or out
    assert not (tmp_path / "escaped").exists() and not os.path.exists("/tmp/escaped")


def test_resume_tries_every_failed_plant_again_and_says_how_many(tmp_path, monkeypatch):
    """A plant failed on a full disk (recorded as the trainer reports it: its message): after
    space is freed, `generate --resume` finishes it, as a dataset rerun would."""
    from plantdreamer.pipeline.runs import sequence

    export = sequence.export_run

    def disk_full_for_the_second(cfg, state, folder, *args):
        if folder.name == "bean-s0001":
            raise OSError(28, "No space left on device")
        return export(cfg, state, folder, *args)

    monkeypatch.setattr(sequence, "export_run", disk_full_for_the_second)
    out = tmp_path / "g"
    args = ["generate", "--species", "bean", "--seeds", "0,1", "--guidance", "none", "--steps",
            "1", "--points", "300", "--resolution", "16", "--eval-views", "1", "--turntable",
            "none"]  # fmt: skip
    first = CliRunner().invoke(main, [*args, "--out", str(out), "--quiet"])
    assert first.exit_code == 1 and "No space left" in first.output, first.output
    record = json.loads((out / "group.json").read_text())
    for entry in record["plants"]:  # as a failure in training is recorded: its message only
        entry.pop("retry", None)
    (out / "group.json").write_text(json.dumps(record))
    monkeypatch.setattr(sequence, "export_run", export)
    again = CliRunner().invoke(main, ["generate", "--resume", str(out)])
    assert again.exit_code == 0, again.output
    assert "retrying 1 plants that failed before: bean-s0001" in again.output
    statuses = [p["status"] for p in json.loads((out / "group.json").read_text())["plants"]]
    assert statuses == ["done", "done"] and (out / "bean-s0001" / "run.json").is_file()


def test_view_with_its_port_taken_is_refused_before_the_run(tmp_path):
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        out = tmp_path / "o"
        args = ["generate", *TINY, "--steps", "0", "--view", "--port", port, "--out", out]
        result = CliRunner().invoke(main, [str(a) for a in args])
    assert result.exit_code == 1, result.output
    assert f"port {port} on 127.0.0.1 is in use; choose another with --port" in result.output
    assert not out.exists()


def test_each_plant_records_its_share_of_the_groups_phases(tmp_path, monkeypatch):
    """A phase that ran for several plants is shared among them: with every phase taking
    exactly one tick, the halves of a group of three (two plants, then one) record a half
    and a whole per step; the plants sum to the group's time."""
    from plantdreamer.pipeline.export import STEP_PHASES
    from plantdreamer.pipeline.step import schedule

    ticks = iter(range(10**6))
    monkeypatch.setattr(schedule, "perf_counter", lambda: float(next(ticks)))
    cfgs = [GenerateConfig.of(species="mint", seed=s, steps=2, overlap="on", **SMALL)
            for s in (0, 1, 2)]  # fmt: skip
    result = group(cfgs, tmp_path / "g", guidance=tiny_sds(), show_progress=False)
    names = ["mint-s0000", "mint-s0001", "mint-s0002"]
    for name, share in zip(names, [1.0, 1.0, 2.0], strict=True):
        timings = done(result)[name].timings
        for phase in STEP_PHASES:
            assert timings[phase] == pytest.approx(share), (name, phase)
