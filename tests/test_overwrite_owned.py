"""``--overwrite`` deletes exactly the files the command writes, and nothing else.

A sentinel file and a sentinel folder beside or inside each output must survive an
``--overwrite`` of ``eval``, ``prepare``, ``render`` and a group whose plant names hold
glob characters; an output path that names a folder is refused, never emptied.
"""

import json
import re

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from plantdreamer.cli import main
from plantdreamer.cloud import PointCloud
from plantdreamer.io import write_ply, write_splat_ply
from plantdreamer.pipeline.init import init_gaussians


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def one_error(result, message):
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert result.exit_code == 1 and len(errors) == 1, result.output
    assert "internal error" not in result.output and message in errors[0], result.output


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
    with claim_folder(out, overwrite=True, owned=("group.json", "*-s0000", "*.ply", "[ab]")):
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
