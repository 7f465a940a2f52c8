"""`dataset --plants-per-gpu B`: plants packed into groups trained in one trainer, each with
its own folder and record; a bad plant fails alone; the worker's models are loaded once.

The worker's task and the model cache run in-process here (no Ray); test_dataset_ray.py
runs the command on a local Ray instance.
"""

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from plantdreamer.cli import main
from plantdreamer.dataset import expand
from plantdreamer.dataset.packing import pack, packing_from
from plantdreamer.dataset.tasks import run_unit
from plantdreamer.dataset.worker import ModelCache
from plantdreamer.errors import InputError
from plantdreamer.output_folder import LOCK_NAME
from plantdreamer.pipeline import GenerateConfig, generate_plants
from plantdreamer.pipeline.settings.runtime import build_guidance

SMALL = {"steps": 3, "points": 1500, "resolution": 32, "eval-views": 1, "turntable-frames": 2}


class FakeBoard:
    """The driver's board as a worker sees it (``tasks.Board``), in this process."""

    def __init__(self):
        self.starts = []

    def started(self, plant_id, info):
        self.starts.append(plant_id)

    def stopping(self):
        return False


def test_plants_are_packed_in_spec_order_by_shared_settings():
    spec = {
        "group": [
            {"species": "bean", "count": 3, "guidance": "none"},
            {"species": "mint", "count": 2, "guidance": "none"},
            {"name": "more", "species": "bean", "seeds": [7], "guidance": "none"},
            {"name": "long", "species": "bean", "seeds": [8], "guidance": "none", "steps": 9},
        ]
    }
    plants = expand(spec)
    ids = [[p.id for p in g] for g in pack(plants, 2)]
    assert ids == [
        ["bean-s0000", "bean-s0001"],
        ["bean-s0002", "more-bean-s0007"],  # another [[group]], the same settings
        ["mint-s0000", "mint-s0001"],
        ["long-bean-s0008"],  # other settings: a group of its own
    ]
    assert [[p.id for p in g] for g in pack(plants, 1)] == [[p.id] for p in plants]


def test_plants_per_gpu_is_one_setting_in_the_spec_and_on_the_command_line():
    assert packing_from({}, {}).plants_per_gpu == 1
    assert packing_from({"plants-per-gpu": 4}, {}).plants_per_gpu == 4
    assert packing_from({"plants_per_gpu": 4}, {"plants-per-gpu": 2}).plants_per_gpu == 2
    for bad in (0, 65, "4", True):
        with pytest.raises(InputError, match="plants-per-gpu"):
            packing_from({"plants-per-gpu": bad}, {})
    assert len(expand({"plants-per-gpu": 3, "group": [{"species": "bean"}]})) == 1
    with pytest.raises(InputError, match="plants-per-gpu at the top"):
        expand({"plants_per_gpus": 3, "group": [{"species": "bean"}]})
    result = CliRunner().invoke(main, ["dataset", "--help"])
    assert "--plants-per-gpu" in result.output and "1<=x<=64" in result.output


def _request(out, plants, threads=1):
    return {
        "plants": [
            {"id": p.id, "config": p.config.to_dict(), "plant_dir": str(out / "plants" / p.id)}
            for p in plants
        ],
        "threads": threads,
    }


def _clouds(folder):
    from plantdreamer.cloud import PointCloud
    from plantdreamer.io import write_ply

    folder.mkdir()
    rng = np.random.default_rng(0)
    for name in ("a", "c"):
        pts = (rng.normal(size=(2000, 3)) * [0.2, 0.2, 0.5]).astype(np.float32)
        write_ply(folder / f"{name}.ply", PointCloud(pts, colors=rng.random((2000, 3), np.float32)))
    (folder / "b.ply").write_bytes(b"ply\nformat nonsense\n")


@pytest.mark.slow
def test_a_packed_group_writes_each_plant_folder_and_a_bad_plant_fails_alone(tmp_path):
    _clouds(tmp_path / "clouds")
    spec = {
        "base_dir": str(tmp_path),
        "group": [{"pointclouds": "clouds/*.ply", "species": "bean", "guidance": "none", **SMALL}],
    }
    plants = expand(spec)
    (group,) = pack(plants, 3)
    out = tmp_path / "out"
    out.mkdir()
    (out / LOCK_NAME).touch()  # the dataset's lock: a worker checks that it sees the folder
    board = FakeBoard()
    results = run_unit(_request(out, group), board, ModelCache().guidance_for, None)
    assert board.starts == ["a-s0000", "b-s0000", "c-s0000"]
    assert {i: r["status"] for i, r in results.items()} == {
        "a-s0000": "done", "b-s0000": "failed", "c-s0000": "done"
    }  # fmt: skip
    assert "PlyError" in results["b-s0000"]["error"] and "\n" not in results["b-s0000"]["error"]
    # b failed its input check before training: a and c trained together, without it.
    assert results["a-s0000"]["trained_with"] == ["a-s0000", "c-s0000"]
    assert sorted(p.name for p in out.iterdir()) == [LOCK_NAME, "plants"]  # nothing beside
    for plant_id in ("a-s0000", "c-s0000"):
        folder = out / "plants" / plant_id
        for name in ("plant.ply", "run.json", "transforms.json", "generate.log"):
            assert (folder / name).is_file(), (plant_id, name)
        assert not (folder / "checkpoint.pt").exists()
        # Without guidance a plant trained in a group is the plant trained alone.
        alone = generate_plants([plant_config(group, plant_id)], tmp_path / plant_id,
                                show_progress=False)[0]  # fmt: skip
        assert (folder / "plant.ply").read_bytes() == alone.ply_path.read_bytes()
    assert "group of 3" in (out / "plants" / "c-s0000" / "generate.log").read_text()


def plant_config(plants, plant_id):
    return next(p.config for p in plants if p.id == plant_id)


@pytest.fixture(scope="module")
def tiny_model_folders(tmp_path_factory):
    from plantdreamer.guidance import save_tiny_models

    base, controlnet = save_tiny_models(tmp_path_factory.mktemp("tiny"))
    return str(base), str(controlnet)


def _sds_config(models, seed):
    base, controlnet = models
    return GenerateConfig.of(
        species="mint", seed=seed, base_model=base, controlnet=controlnet, device="cpu",
        sds_resolution=64, **{k.replace("-", "_"): v for k, v in SMALL.items()},
    )  # fmt: skip


@pytest.mark.slow
def test_a_worker_loads_the_models_once_and_each_plant_is_the_plant_of_a_fresh_load(
    tiny_model_folders, tmp_path
):
    from plantdreamer.pipeline.settings.group_settings import GroupSettings
    from plantdreamer.pipeline.settings.runtime import resolve_plants

    cache = ModelCache()
    out = tmp_path / "out"
    (out / "plants").mkdir(parents=True)
    (out / LOCK_NAME).touch()
    board = FakeBoard()
    for seed in (0, 1):
        cfg = _sds_config(tiny_model_folders, seed)
        request = {"plants": [{"id": f"p{seed}", "config": cfg.to_dict(),
                               "plant_dir": str(out / "plants" / f"p{seed}")}],
                   "threads": 1}  # fmt: skip
        result = run_unit(request, board, cache.guidance_for, None)[f"p{seed}"]
        assert result["status"] == "done" and result["trained_with"] == [f"p{seed}"], result
    assert cache.loads == 1  # the second plant used the first one's networks
    for seed in (0, 1):  # ... and got the bytes of a guidance loaded from disk for it
        cfg = _sds_config(tiny_model_folders, seed)
        resolved = GenerateConfig.from_dict(cfg.to_dict())
        resolve_plants([resolved])
        guidance = build_guidance(GroupSettings.of([resolved]))
        fresh = generate_plants([cfg], tmp_path / f"fresh{seed}", guidance=guidance,
                                show_progress=False)[0]  # fmt: skip
        ours = Path(out / "plants" / f"p{seed}" / "plant.ply").read_bytes()
        assert ours == fresh.ply_path.read_bytes(), seed
    run = json.loads((out / "plants" / "p1" / "run.json").read_text())
    assert run["config"]["base-model"] == tiny_model_folders[0]


def _interrupt_at(stop_step):
    """What a worker does when the driver asks it to stop: Ctrl-C in its own main thread."""
    import _thread

    def hook(step):
        if step == stop_step:
            _thread.interrupt_main()

    return hook


def _group_outputs(out, ids):
    skip = {"run.json", "generate.log"}
    return {
        f"{i}/{p.relative_to(out / 'plants' / i)}": p.read_bytes()
        for i in ids
        for p in sorted((out / "plants" / i).rglob("*"))
        if p.is_file() and p.name not in skip
    }


@pytest.mark.slow
def test_a_stopped_sds_group_resumes_in_a_later_run_byte_identical(tiny_model_folders, tmp_path):
    base, controlnet = tiny_model_folders
    spec = {
        "group": [{"species": "mint", "count": 2, "base-model": base, "controlnet": controlnet,
                   "device": "cpu", "sds-resolution": 64, "checkpoint-every": 2,
                   **{**SMALL, "steps": 6}}]
    }  # fmt: skip
    (group,) = pack(expand(spec), 2)
    ids = [p.id for p in group]
    outs = {}
    for name in ("straight", "stopped"):
        out = outs[name] = tmp_path / name
        (out / "plants").mkdir(parents=True)
        (out / LOCK_NAME).touch()
    straight = run_unit(_request(outs["straight"], group), FakeBoard(), ModelCache().guidance_for,
                         None)  # fmt: skip
    assert {r["status"] for r in straight.values()} == {"done"}
    stopped = run_unit(_request(outs["stopped"], group), FakeBoard(), ModelCache().guidance_for,
                        _interrupt_at(2))  # fmt: skip
    assert {r["error"] for r in stopped.values()} == {"interrupted at step 3"}
    # The unit's noise state, saved once, in its first plant's folder for the rerun.
    assert (outs["stopped"] / "plants" / ids[0] / "noise.pt").is_file()
    assert not (outs["stopped"] / "plants" / ids[1] / "noise.pt").exists()
    assert sorted(p.name for p in outs["stopped"].iterdir()) == [LOCK_NAME, "plants"]
    resumed = run_unit(_request(outs["stopped"], group), FakeBoard(), ModelCache().guidance_for,
                        None)  # fmt: skip
    assert [resumed[i]["resumed_from_step"] for i in ids] == [3, 3]
    assert _group_outputs(outs["stopped"], ids) == _group_outputs(outs["straight"], ids)


def test_a_plant_failed_before_a_stop_is_recorded_failed_not_interrupted(tmp_path):
    _clouds(tmp_path / "clouds")
    spec = {
        "base_dir": str(tmp_path),
        "group": [{"pointclouds": "clouds/*.ply", "species": "bean", "guidance": "none",
                   **{**SMALL, "steps": 4}}],
    }  # fmt: skip
    (group,) = pack(expand(spec), 3)
    out = tmp_path / "out"
    out.mkdir()
    (out / LOCK_NAME).touch()
    results = run_unit(_request(out, group), FakeBoard(), ModelCache().guidance_for,
                        _interrupt_at(1))  # fmt: skip
    assert {i: r["status"] for i, r in results.items()} == {
        "a-s0000": "interrupted", "b-s0000": "failed", "c-s0000": "interrupted"
    }  # fmt: skip
    assert "PlyError" in results["b-s0000"]["error"]


def test_a_worker_checks_the_lora_before_any_model_loads(tmp_path):
    settings = {**SMALL, "guidance": "sds", "lora": str(tmp_path / "missing" / "bean")}
    (plant,) = expand({"group": [{"species": "bean", **settings}]})
    (tmp_path / LOCK_NAME).touch()  # the driver's lock: the worker sees the folder

    def no_load(cfg):
        raise AssertionError("a model was loaded")

    record = run_unit(_request(tmp_path, [plant]), FakeBoard(), no_load, None)[plant.id]
    assert record["status"] == "failed" and "LoRA" in record["error"], record
