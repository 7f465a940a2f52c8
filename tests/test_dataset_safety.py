"""`dataset` touches only its own folder, checks every input before Ray starts, and keeps its
manifest true to the plant folders through any stop (no worker started here: a stop while
the workers start is a KeyboardInterrupt from ``runner.open_workers``)."""

import json
import os

import pytest
from click.testing import CliRunner

from plantdreamer.cli import main
from plantdreamer.dataset import RunOptions, expand, plan, run_dataset, runner
from plantdreamer.dataset.manifest import Manifest
from plantdreamer.dataset.plant import Plant
from plantdreamer.errors import InputError, PlantDreamerError
from plantdreamer.exports import LabelOptions

FAST = ["--guidance", "none", "--steps", "0", "--eval-views", "0", "--quiet"]


def invoke(*args):
    return CliRunner().invoke(main, ["dataset", *map(str, args)])


def one_line_error(result, message):
    assert result.exit_code == 1, result.output
    assert "Traceback" not in result.output and "internal error" not in result.output
    assert f"error: {message}" in result.output or message in result.output, result.output


# -- cause 1: a group name is never a path -----------------------------------------------


@pytest.mark.parametrize("name", ["{outside}/keep/important", "../../keep/important", "a/b"])
def test_a_group_name_that_is_a_path_is_refused_and_nothing_outside_is_touched(tmp_path, name):
    keep = tmp_path / "keep"
    victim = keep / "important-bean-s0000"
    victim.mkdir(parents=True)
    (victim / "sentinel.txt").write_text("mine")
    out = tmp_path / "work" / "ds"
    spec = tmp_path / "spec.toml"
    spec.write_text(f'[[group]]\nname = "{name.format(outside=tmp_path)}"\nspecies = "bean"\n')
    result = invoke(spec, "--out", out, *FAST)
    one_line_error(result, "never a path")
    assert (victim / "sentinel.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep", "spec.toml"]  # no out either


def test_group_names_must_be_folder_name_strings():
    for name in ("", "bean_2.a", "A-1"):
        expand({"group": [{"name": name, "species": "bean"}]})
    for name in (".hidden", "a b", "x\\y", "a" * 101):
        with pytest.raises(InputError, match="never a path"):
            expand({"group": [{"name": name, "species": "bean"}]})
    with pytest.raises(InputError, match="'name' must be a string"):
        expand({"group": [{"name": [1, 2], "species": "bean"}]})


def test_point_cloud_file_names_become_safe_folder_names(tmp_path):
    (tmp_path / "my scan#1.ply").write_bytes(b"ply")
    (tmp_path / ".dot.ply").write_bytes(b"ply")
    groups = [{"pointclouds": "*.ply"}, {"pointclouds": ".dot.ply"}]  # * skips dot files
    plants = expand({"base_dir": str(tmp_path), "group": groups})
    assert sorted(p.id for p in plants) == ["dot-s0000", "my_scan_1-s0000"]


def test_a_plant_folder_outside_the_plants_folder_is_refused(tmp_path):
    (plant,) = expand({"group": [{"species": "bean", "guidance": "none"}]})
    bad = Plant("../escape", plant.group, plant.config, plant.config_hash)
    with pytest.raises(PlantDreamerError, match="not a folder name"):
        plan.plant_dir(tmp_path, bad)


# -- cause 2: a record changes before its files -------------------------------------------


def _finished_dataset(out, plants):
    """A dataset as an earlier run left it: every plant done, with its files."""
    manifest = Manifest(out)
    for plant in plants:
        folder = out / "plants" / plant.id
        folder.mkdir(parents=True)
        for name in ("plant.ply", "run.json", "checkpoint.pt"):
            (folder / name).write_text("x")
        manifest.replace(plant.id, {"status": "done", "config_hash": plant.config_hash})


def _check_manifest_against_folders(out):
    for plant_id, record in Manifest(out).records.items():
        if record["status"] == "done":
            folder = out / "plants" / plant_id
            assert (folder / "plant.ply").is_file() and (folder / "run.json").is_file(), plant_id


def test_a_rerun_stopped_while_ray_starts_leaves_no_done_record_without_files(
    tmp_path, monkeypatch
):
    spec = {"group": [{"species": "bean", "count": 3, "guidance": "none"}]}
    _finished_dataset(tmp_path, expand(spec))
    changed = {**spec, "defaults": {"steps": 7}}

    def ctrl_c_while_workers_start(*_args):
        raise KeyboardInterrupt

    monkeypatch.setattr(runner, "open_workers", ctrl_c_while_workers_start)
    with pytest.raises(KeyboardInterrupt):
        labels = LabelOptions(allow_empty_split=True)  # 3 plants: val may draw none
        run_dataset(
            changed,
            expand(changed),
            tmp_path,
            RunOptions(show_progress=False, redo_changed=True, labels=labels),
        )
    records = Manifest(tmp_path).records
    assert {r["status"] for r in records.values()} == {"pending"}
    assert not any((tmp_path / "plants").iterdir())
    _check_manifest_against_folders(tmp_path)
    summary = json.loads((tmp_path / "dataset.json").read_text())
    assert summary["state"] == "stopped"


def test_the_record_changes_before_any_file_is_deleted(tmp_path, monkeypatch):
    """A SIGKILL can come at any instant: at each deletion the record on disk is already
    no longer `done`."""
    spec = {"group": [{"species": "bean", "count": 2, "guidance": "none"}]}
    _finished_dataset(tmp_path, expand(spec))
    real_clear, seen = plan.clear_plant_folder, []

    def checked_clear(folder):
        assert Manifest(tmp_path).get(folder.name)["status"] == "pending"
        seen.append(folder.name)
        real_clear(folder)

    monkeypatch.setattr(plan, "clear_plant_folder", checked_clear)
    changed = {**spec, "defaults": {"steps": 7}}
    todo, skipped = plan.plan(expand(changed), Manifest(tmp_path), tmp_path, 1, redo_changed=True)
    assert len(todo) == 2 and not skipped and sorted(seen) == ["bean-s0000", "bean-s0001"]


def test_a_clearing_cut_short_is_finished_by_the_next_run(tmp_path):
    """Killed while clearing: the record says `pending` with the new config; whatever of the
    old config's folder is left (its checkpoint) must not be resumed."""
    spec = {"group": [{"species": "bean", "guidance": "none"}]}
    (plant,) = expand(spec)
    folder = tmp_path / "plants" / plant.id
    folder.mkdir(parents=True)
    (folder / "checkpoint.pt").write_text("the old config's")
    Manifest(tmp_path).replace(plant.id, {"status": "pending", "config_hash": plant.config_hash})
    todo, _ = plan.plan([plant], Manifest(tmp_path), tmp_path, 1)
    assert todo == [plant] and not folder.exists()


def test_a_done_plant_missing_a_file_runs_again(tmp_path):
    spec = {"group": [{"species": "bean", "count": 2, "guidance": "none"}]}
    plants = expand(spec)
    _finished_dataset(tmp_path, plants)
    (tmp_path / "plants" / "bean-s0001" / "run.json").unlink()
    todo, skipped = plan.plan(plants, Manifest(tmp_path), tmp_path, 1)
    assert [p.id for p in skipped] == ["bean-s0000"] and [p.id for p in todo] == ["bean-s0001"]
    assert (tmp_path / "plants" / "bean-s0001" / "checkpoint.pt").is_file()  # same config


# -- causes 6 and 7: clear errors, before Ray starts --------------------------------------


@pytest.mark.parametrize(
    ("spec_bytes", "message"),
    [
        (b"defaults = 5\n", "[defaults] must be a table"),
        (b'[[group]]\nspecies = "be\xffan"\n', "not UTF-8 text"),
        (b'[[group]]\nspecies = "bean"\nseeds = []\n', "'seeds' is empty"),
        (b'[[group]]\nspecies = "bean"\ncount = true\n', "'count' must be an integer"),
        (b'[[group]]\nspecies = "beanz"\n', "unknown species 'beanz'"),
        (b'[[group]]\nspecies = "bean"\nlora = [1, 2]\n', "lora must be a string or none"),
        (
            b'[[group]]\nspecies = "bean"\nlr = 5\n',
            "'lr' is not one setting; give each by name: lr-means, lr-sh-dc",
        ),
    ],
)
def test_bad_specs_are_one_line_errors_before_ray(tmp_path, spec_bytes, message):
    spec = tmp_path / "spec.toml"
    spec.write_bytes(spec_bytes)
    one_line_error(invoke(spec, "--out", tmp_path / "out", *FAST), message)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--set", "lora=[1,2]"], "lora must be a string or none, got [1, 2]"),
        (["--set", "cameras-distance=[1, 2, 3]"], "cameras-distance must be a list of 2"),
        (["--resource", "disk=-1"], "--resource disk=-1: the amount must be a number"),
        (["--resource", "disk=nan"], "the amount must be a number"),
        (["--resource", "CPU=1"], "--resource CPU: use --cpus-per-plant"),
        (["--resource", "memory=1"], "Ray manages 'memory' itself"),
        (["--cpus-per-plant", "nan"], "--cpus-per-plant must be >= 1, got nan"),
        (["--gpus-per-plant", "-1"], "--gpus-per-plant must be >= 0, got -1.0"),
    ],
)
def test_bad_settings_are_one_line_errors_before_ray(tmp_path, args, message):
    ray = pytest.importorskip("ray")
    result = invoke("--species", "bean", "--out", tmp_path / "out", *FAST, *args)
    one_line_error(result, message)
    assert not ray.is_initialized()


def test_a_manifest_line_without_status_is_a_clear_error(tmp_path):
    (tmp_path / "manifest.jsonl").write_text('{"id": "bean-s0000"}\n')
    one_line_error(
        invoke("--species", "bean", "--out", tmp_path, *FAST), "has status None, not one of"
    )


def test_a_replaced_scan_at_the_same_path_is_a_new_config(tmp_path):
    scan = tmp_path / "scan.ply"
    scan.write_bytes(b"first")
    spec = {"base_dir": str(tmp_path), "group": [{"pointclouds": "scan.ply", "species": "bean"}]}
    (before,) = expand(spec)
    scan.write_bytes(b"other")
    (after,) = expand(spec)
    assert before.config == after.config and before.config_hash != after.config_hash


# -- cause 8: one appended line per change ------------------------------------------------


def test_a_change_appends_one_line_and_a_reopen_compacts(tmp_path):
    manifest = Manifest(tmp_path)
    for plant_id in ("a", "b"):
        manifest.replace(plant_id, {"status": "running"})
    before = (tmp_path / "manifest.jsonl").read_bytes()
    manifest.update("a", status="done")
    after = (tmp_path / "manifest.jsonl").read_bytes()
    assert after.startswith(before) and after.count(b"\n") == 3  # appended, not rewritten
    reopened = Manifest(tmp_path)
    assert reopened.get("a")["status"] == "done" and list(reopened.records) == ["a", "b"]
    assert (tmp_path / "manifest.jsonl").read_bytes().count(b"\n") == 2  # compacted


def test_a_line_cut_short_by_a_kill_is_dropped(tmp_path):
    manifest = Manifest(tmp_path)
    manifest.replace("a", {"status": "running"})
    with open(tmp_path / "manifest.jsonl", "ab") as f:
        f.write(b'{"id": "a", "sta')  # the driver died inside this write
    assert Manifest(tmp_path).get("a")["status"] == "running"
    assert (tmp_path / "manifest.jsonl").read_bytes().endswith(b"}\n")


def test_the_file_stays_within_a_few_lines_per_plant(tmp_path):
    manifest = Manifest(tmp_path)
    for i in range(10):
        manifest.replace(f"p{i}", {"status": "running"})
    for _ in range(100):
        manifest.update("p0", status="running", attempt=1)
    lines = (tmp_path / "manifest.jsonl").read_bytes().count(b"\n")
    assert lines <= 3 * 10 + 64 + 1
    assert Manifest(tmp_path).records == manifest.records
    assert not [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]


def test_changing_plants_per_gpu_keeps_finished_plants_and_restarts_unfinished_ones(tmp_path):
    """An SDS plant's bytes depend on its group: a finished plant is kept whatever B made
    it (its record says which), a checkpoint made under another B is not resumed."""
    spec = {"group": [{"species": "bean", "count": 3, "guidance": "none"}]}
    plants = expand(spec)
    _finished_dataset(tmp_path, plants)
    manifest = Manifest(tmp_path)
    for plant in plants:
        manifest.update(plant.id, plants_per_gpu=4)
    manifest.update("bean-s0001", status="interrupted")
    manifest.replace("bean-s0002", {"status": "interrupted", "config_hash": plants[2].config_hash})
    for name in ("plant.ply", "run.json"):
        (tmp_path / "plants" / "bean-s0001" / name).unlink()
        (tmp_path / "plants" / "bean-s0002" / name).unlink()
    todo, skipped = plan.plan(plants, Manifest(tmp_path), tmp_path, 4)
    assert [p.id for p in skipped] == ["bean-s0000"]  # same B: the checkpoints resume
    assert (tmp_path / "plants" / "bean-s0001" / "checkpoint.pt").is_file()
    todo, skipped = plan.plan(plants, Manifest(tmp_path), tmp_path, 2)
    assert [p.id for p in skipped] == ["bean-s0000"] and len(todo) == 2
    assert not (tmp_path / "plants" / "bean-s0001").exists()  # started under B = 4
    assert (tmp_path / "plants" / "bean-s0002" / "checkpoint.pt").is_file()  # B not recorded
    records = Manifest(tmp_path).records
    assert records["bean-s0000"]["plants_per_gpu"] == 4  # the group that made it
    assert (records["bean-s0001"]["status"], records["bean-s0001"]["plants_per_gpu"]) == (
        "pending",
        2,
    )


# -- the exports' folders are the dataset's own; a finished plant is found by its files ------


def test_a_dataset_into_a_project_with_its_own_yolo_files_is_refused(tmp_path):
    project = tmp_path / "project"
    mine = project / "yolo" / "images" / "train" / "mine.png"
    mine.parent.mkdir(parents=True)
    mine.write_bytes(b"a user's picture")
    (project / "coco").mkdir()
    (project / "coco" / "train.json").write_text("a user's labels")  # a name the export writes
    result = invoke("--out", project, "--species", "bean", *FAST, "--split", "1,0,0")
    one_line_error(result, "yolo/images/train/mine.png")
    assert mine.read_bytes() == b"a user's picture"
    assert not (project / "plants").exists()


def _finished_plant_without_record(out, plant, config=None):
    folder = out / "plants" / plant.id
    folder.mkdir(parents=True)
    (folder / "plant.ply").write_text("x")
    run_json = {"config": (config or plant.config).to_dict()}
    (folder / "run.json").write_text(json.dumps(run_json))
    return folder


def test_a_finished_plant_whose_line_was_deleted_is_kept_and_the_dry_run_agrees(tmp_path):
    spec = {"group": [{"species": "bean", "count": 2, "guidance": "none"}]}
    plants = expand(spec)
    folder = _finished_plant_without_record(tmp_path, plants[0])
    lines = plan.describe_plan(plants, Manifest(tmp_path, read_only=True), tmp_path, 1)
    assert "skip    bean-s0000" in lines and "make    bean-s0001" in lines
    todo, skipped = plan.plan(plants, Manifest(tmp_path), tmp_path, 1)
    assert [p.id for p in skipped] == ["bean-s0000"] and [p.id for p in todo] == ["bean-s0001"]
    assert (folder / "plant.ply").read_text() == "x"
    assert Manifest(tmp_path).get("bean-s0000")["status"] == "done"


def test_a_finished_plant_of_other_settings_without_its_line_is_a_redo(tmp_path):
    (plant,) = expand({"group": [{"species": "bean", "guidance": "none", "steps": 3}]})
    (other,) = expand({"group": [{"species": "bean", "guidance": "none", "steps": 5}]})
    folder = _finished_plant_without_record(tmp_path, plant, other.config)
    lines = plan.describe_plan([plant], Manifest(tmp_path, read_only=True), tmp_path, 1)
    assert "redo    bean-s0000" in lines
    with pytest.raises(InputError, match="--redo-changed"):
        plan.plan([plant], Manifest(tmp_path), tmp_path, 1)
    assert (folder / "plant.ply").read_text() == "x"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--stuff", "dirt", "--allow-empty-split"], "--stuff names no class 'dirt'"),
        (["--stuff", "leaf,stem,pot,soil", "--allow-empty-split"], "--stuff names every class"),
        ([], "drew no plant"),  # one plant: val and test empty
    ],
)
@pytest.mark.parametrize("dry_run", [True, False])
def test_label_options_the_run_would_refuse_are_refused_first(tmp_path, args, message, dry_run):
    """Before any plant is made (and by --dry-run, which showed a clean plan)."""
    ray = pytest.importorskip("ray")
    out = tmp_path / "out"
    run_args = ["--dry-run"] if dry_run else []
    result = invoke("--species", "bean", "--count", 1, "--out", out, *FAST, *args, *run_args)
    one_line_error(result, message)
    assert not ray.is_initialized() and not (out / "plants").exists()
