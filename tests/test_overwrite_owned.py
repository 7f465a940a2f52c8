"""``--overwrite`` deletes exactly the files the command writes, and nothing else.

A sentinel file and a sentinel folder beside or inside each output must survive an
``--overwrite`` of ``eval``, ``prepare``, ``render`` and a group whose plant names hold
glob characters; an output path that names a folder is refused, never emptied.
"""

import json
import re
import shutil

import numpy as np
import pytest
from PIL import Image

from cli_run import one_error, run
from plantdreamer.cloud import PointCloud
from plantdreamer.io import write_ply, write_splat_ply
from plantdreamer.pipeline.model.init import init_gaussians
from plantdreamer.temporaries import temporary_name


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("inputs")
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(300, 3)).astype(np.float32)
    write_splat_ply(d / "model.ply", init_gaussians(pts, None, 0.5))
    write_ply(d / "cloud.ply", PointCloud(pts, colors=rng.random((300, 3), dtype=np.float32)))
    ds = d / "ds"
    ds.mkdir()
    Image.new("RGB", (16, 12)).save(ds / "a.png")
    frame = {"file_path": "a.png", "transform_matrix": np.eye(4).tolist(), "fl_x": 20.0}
    (ds / "transforms.json").write_text(json.dumps({"frames": [frame]}))
    return d


def sentinels(folder):
    """A user's file and folder (with a file inside) in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "holiday.png").write_bytes(b"my holiday")
    (folder / "notes").mkdir(exist_ok=True)
    (folder / "notes" / "keep.txt").write_text("mine")


def intact(folder):
    return (folder / "holiday.png").read_bytes() == b"my holiday" and (
        folder / "notes" / "keep.txt"
    ).read_text() == "mine"


def test_eval_overwrite_refuses_a_folder_named_by_out(files, tmp_path):
    out = tmp_path / "report.md"
    sentinels(out)  # a folder where the report would go
    args = ["eval", files / "model.ply", "--dataset", files / "ds", "--strip-views", 0]
    one_error(run(*args, "--out", out, "--overwrite"), "folder")
    assert intact(out)
    sentinels(tmp_path)
    assert run(*args, "--out", out.with_name("r.md"), "--overwrite").exit_code == 0
    assert intact(tmp_path)


def test_eval_out_must_be_the_markdown_report(files, tmp_path):
    args = ["eval", files / "model.ply", "--dataset", files / "ds", "--strip-views", 0]
    one_error(run(*args, "--out", "."), "--out")
    one_error(run(*args, "--out", tmp_path / "report.json"), "report.json")
    assert not (tmp_path / "report.json").exists()


def test_prepare_overwrite_refuses_a_folder_named_by_output(files, tmp_path):
    out = tmp_path / "p.ply"
    sentinels(out)
    args = ["prepare", files / "cloud.ply", "--target", 0, "--sor-neighbors", 0, "--overwrite"]
    one_error(run(*args, "-o", out), "folder")
    assert intact(out)
    one_error(run(*args, "-o", tmp_path), "folder")
    sentinels(tmp_path)
    assert run(*args, "-o", tmp_path / "q.ply").exit_code == 0
    assert intact(tmp_path) and intact(out)


def test_render_overwrite_keeps_the_users_pictures(files, tmp_path):
    out = tmp_path / "pictures"
    sentinels(out)
    (out / "view_099.png").write_bytes(b"an earlier render's view")
    args = ["render", files / "model.ply", "--out", out, "--views", 2, "--resolution", 16,
            "--turntable", "none"]  # fmt: skip
    one_error(run(*args), "--overwrite")
    result = run(*args, "--overwrite")
    assert result.exit_code == 0, result.output
    assert intact(out)
    assert not (out / "view_099.png").exists()  # the earlier render's own file is replaced
    assert sorted(p.name for p in out.iterdir()) == [
        "holiday.png",
        "notes",
        "view_000.png",
        "view_001.png",
    ]


def test_owned_names_are_literal_not_glob_patterns(tmp_path):
    from plantdreamer.output_folder import claim_folder

    out = tmp_path / "group"
    sentinels(out)
    (out / "bean-s0000").mkdir()
    (out / "x.ply").write_text("a user's point cloud")
    (out / "[ab]").mkdir()
    (out / "a").mkdir()
    owned = ("group.json", "*-s0000/", "*.ply", "[ab]/")
    with claim_folder(out, overwrite=True, owned=owned):
        pass
    assert intact(out)
    assert (out / "bean-s0000").is_dir() and (out / "x.ply").is_file() and (out / "a").is_dir()
    assert not (out / "[ab]").exists()  # the literal name is the command's own
    with claim_folder(out, overwrite=True, owned=(re.compile(r"view_\d{3,}\.png"),)):
        pass
    assert intact(out)


def test_owned_names_never_reach_outside_the_folder(tmp_path):
    from plantdreamer.errors import InputError
    from plantdreamer.output_folder import claim_folder

    sentinels(tmp_path / "elsewhere")
    for name in ("../elsewhere", "/tmp", "a/../../elsewhere"):
        with pytest.raises(InputError, match="not a name"):
            with claim_folder(tmp_path / "out", overwrite=True, owned=(name,)):
                pass
    assert intact(tmp_path / "elsewhere")


def test_group_overwrite_with_glob_characters_in_plant_names(tmp_path):
    """A point cloud named ``*.ply`` makes plants ``*-s0000``: --overwrite of the group
    must not delete every entry ending in ``-s0000``."""
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(200, 3)).astype(np.float32)
    cloud = tmp_path / "*.ply"
    write_ply(cloud, PointCloud(pts, colors=rng.random((200, 3), dtype=np.float32)))
    out = tmp_path / "g"
    sentinels(out)
    (out / "bean-s0000").mkdir()
    (out / "bean-s0000" / "keep.txt").write_text("another plant's")
    args = ["generate", "--pointcloud", cloud, "--seeds", "0,1", "--guidance", "none", "--steps",
            "0", "--points", "200", "--resolution", "16", "--eval-views", "1", "--turntable",
            "none", "--out", out, "--quiet", "--overwrite"]  # fmt: skip
    result = run(*args)
    assert result.exit_code == 0, result.output
    assert intact(out) and (out / "bean-s0000" / "keep.txt").read_text() == "another plant's"
    # The plants are named from the cloud's file name, made a plain name ("_-s0000").
    names = [entry["name"] for entry in json.loads((out / "group.json").read_text())["plants"]]
    assert names == ["_-s0000", "_-s0001"]
    assert all((out / name / "run.json").is_file() for name in names)


# -- one ownership rule: checks first, own files only, no input among the outputs -----------

TINY = ["--guidance", "none", "--points", "300", "--steps", "0", "--eval-views", "1",
        "--resolution", "16", "--turntable", "none", "--quiet"]  # fmt: skip


def finished_run(folder):
    """What a finished run leaves (its own files), as bytes to compare."""
    (folder / "renders").mkdir(parents=True)
    for name in ("run.json", "plant.ply", "renders/view_000.png"):
        (folder / name).write_bytes(f"earlier {name}".encode())
    return snapshot(folder)


def snapshot(folder):
    return {
        p.relative_to(folder).as_posix(): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and not p.is_symlink()
    }


def test_generate_overwrite_refuses_its_folders_holding_a_users_files(tmp_path):
    out = tmp_path / "project"
    for name in ("labels/mine.json", "depth/scan.exr", "renders/notes.txt"):
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_text(f"the user's {name}")
    sentinels(out)
    before = snapshot(out)
    result = run("generate", "--species", "bean", *TINY, "--out", out, "--overwrite")
    one_error(result, "renders/notes.txt")
    assert "labels/mine.json" in result.output and "depth/scan.exr" in result.output
    assert snapshot(out) == before and intact(out)
    # A link where the command writes a folder is refused too, never followed.
    shutil.rmtree(out / "renders")
    sentinels(tmp_path / "elsewhere")
    (out / "renders").symlink_to(tmp_path / "elsewhere")
    one_error(run("generate", "--species", "bean", *TINY, "--out", out, "--overwrite"),
              "renders (a link)")  # fmt: skip
    assert intact(tmp_path / "elsewhere")


def test_generate_overwrite_deletes_its_own_files_and_keeps_the_users(tmp_path):
    out = tmp_path / "run"
    finished_run(out)
    sentinels(out)
    stale = out / "renders" / temporary_name("view_001.png")  # a killed write's temporary
    stale.write_bytes(b"partial")
    (out / temporary_name("checkpoint.pt")).write_bytes(b"partial checkpoint")
    result = run("generate", "--species", "bean", *TINY, "--out", out, "--overwrite")
    assert result.exit_code == 0, result.output
    assert intact(out) and not stale.exists()
    assert not list(out.glob(".*.tmp*")) and (out / "run.json").read_bytes() != b"earlier run.json"


def test_resume_removes_a_killed_writes_temporary(tmp_path):
    from plantdreamer.output_folder import claim_folder
    from plantdreamer.pipeline.state.run_outputs import RUN_OUTPUTS

    out = tmp_path / "run"
    finished_run(out)
    sentinels(out)
    stale = out / temporary_name("checkpoint.pt")
    stale.write_bytes(b"partial checkpoint")
    with claim_folder(out, owned=RUN_OUTPUTS, allow_existing=True):
        pass
    assert not stale.exists()
    assert intact(out) and (out / "run.json").read_bytes() == b"earlier run.json"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--guidance", "sds", "--base-model", "{d}/no-such-model"], "no-such-model"),
        (["--pointcloud", "{d}/notes.txt"], "not a PLY"),
        (["--lora", "{d}/missing/path"], "LoRA"),
        (["--guidance", "sds", "--lora", "{d}/missing/path"], "LoRA"),
    ],
)
def test_generate_overwrite_checks_the_new_run_before_deleting(tmp_path, monkeypatch, args,
                                                               message):  # fmt: skip
    from plantdreamer.guidance import models

    def no_load(*_args, **_kwargs):
        raise AssertionError("a model was loaded")

    monkeypatch.setattr(models, "load_components", no_load)
    (tmp_path / "notes.txt").write_text("not a point cloud")
    out = tmp_path / "plant"
    before = finished_run(out)
    given = [a.format(d=tmp_path) for a in args]
    source = [] if "--pointcloud" in given else ["--species", "bean"]
    one_error(run("generate", *source, *TINY, *given, "--out", out, "--overwrite"), message)
    assert snapshot(out) == before


def test_dataset_dry_run_checks_the_lora(tmp_path):
    result = run("dataset", "--out", tmp_path / "ds", "--species", "bean", "--guidance", "none",
                 "--set", f"lora={tmp_path}/missing", "--dry-run")  # fmt: skip
    one_error(result, "LoRA")
    assert not (tmp_path / "ds").exists()


def test_an_input_among_the_outputs_is_refused(files, tmp_path):
    scan = tmp_path / "scan.ply"
    scan.write_bytes((files / "cloud.ply").read_bytes())
    one_error(run("prepare", scan, "-o", scan, "--overwrite"), "input")
    assert scan.read_bytes() == (files / "cloud.ply").read_bytes()
    folder = tmp_path / "dir"
    folder.mkdir()
    cloud = folder / "plant.ply"
    cloud.write_bytes((files / "cloud.ply").read_bytes())
    one_error(run("generate", "--pointcloud", cloud, *TINY, "--out", folder, "--overwrite"),
              "input")  # fmt: skip
    assert cloud.read_bytes() == (files / "cloud.ply").read_bytes()


def test_render_overwrite_keeps_a_captures_photos_and_transforms(files, tmp_path):
    capture = tmp_path / "capture"
    capture.mkdir()
    photo = np.full((12, 16, 3), 200, np.uint8)
    Image.fromarray(photo).save(capture / "0001.png")
    frame = {"file_path": "0001.png", "transform_matrix": np.eye(4).tolist(), "fl_x": 20.0}
    (capture / "transforms.json").write_text(json.dumps({"frames": [frame]}))
    before = snapshot(capture)
    args = ["render", files / "model.ply", "--transforms", capture / "transforms.json"]
    one_error(run(*args, "--out", capture, "--overwrite"), "input")
    one_error(run(*args, "--labels", "--out", capture, "--overwrite"), "input")
    assert snapshot(capture) == before


def test_render_overwrite_keeps_what_another_mode_writes(files, tmp_path):
    out = tmp_path / "r"
    out.mkdir()
    for name in ("transforms.json", "points.ply", "coco.json"):
        (out / name).write_text(f"mine: {name}")
    sentinels(out / "labels")
    before = snapshot(out)
    args = ["render", files / "model.ply", "--out", out, "--views", 1, "--resolution", 16,
            "--turntable", "none", "--overwrite"]  # fmt: skip
    assert run(*args).exit_code == 0
    assert all(snapshot(out)[k] == v for k, v in before.items())


def test_prepare_and_eval_check_their_inputs_before_deleting(files, tmp_path):
    out = tmp_path / "p.ply"
    out.write_bytes(b"an earlier output")
    one_error(run("prepare", tmp_path / "missing.ply", "-o", out, "--overwrite"), "missing.ply")
    assert out.read_bytes() == b"an earlier output"
    report = tmp_path / "r.md"
    report.write_text("an earlier report")
    one_error(run("eval", files / "model.ply", "--dataset", tmp_path / "nothere", "--out", report,
                  "--overwrite"), "nothere")  # fmt: skip
    assert report.read_text() == "an earlier report"


def test_lora_species_is_a_name_and_the_photos_are_checked_first(files, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    sentinels(tmp_path / "checkpoints")
    sentinels(tmp_path / "validation")
    for species in ("..", "../../x", "a/b"):
        one_error(run("lora", "train", files / "ds", "--species", species, "--overwrite"),
                  "--species")  # fmt: skip
    assert intact(tmp_path / "checkpoints") and intact(tmp_path / "validation")
    out = tmp_path / "lora"
    out.mkdir()
    (out / "lora.json").write_text("an earlier LoRA")
    one_error(run("lora", "train", tmp_path / "no-photos", "--out", out, "--overwrite"),
              "no-photos")  # fmt: skip
    assert (out / "lora.json").read_text() == "an earlier LoRA"


@pytest.mark.parametrize("option", ["-o", "--mesh"])
def test_lsystem_refuses_an_existing_file_without_overwrite(tmp_path, option):
    path = tmp_path / ("x.ply" if option == "-o" else "x.glb")
    path.write_bytes(b"mine")
    one_error(run("lsystem", "bean", option, path, "--points", 100), "--overwrite")
    assert path.read_bytes() == b"mine"
    assert run("lsystem", "bean", option, path, "--points", 100, "--overwrite").exit_code == 0
    assert path.read_bytes() != b"mine"


def test_gallery_refuses_an_existing_file_without_overwrite(tmp_path):
    png = tmp_path / "g.png"
    png.write_bytes(b"mine")
    one_error(run("gallery", tmp_path, "--out", png), "--overwrite")
    assert png.read_bytes() == b"mine"


def test_a_failed_demo_rerun_leaves_no_earlier_score(tmp_path):
    from plantdreamer.known_answer.demo import DEMO_JSON, DEMO_PNG
    from plantdreamer.known_answer.demo import main as demo

    out = tmp_path / "demo"
    sentinels(out)
    (out / DEMO_JSON).write_text("{}")
    (out / DEMO_PNG).write_bytes(b"png")
    assert demo([str(out), "--", "false"]) != 0
    assert not (out / DEMO_JSON).exists() and not (out / DEMO_PNG).exists() and intact(out)
