"""A dataset folder's top-level files are the dataset's only once it holds a dataset's
record, and its label files are replaced as a whole: a process stopped between two of the
renames leaves ``export.incomplete``, which ``PlantViews`` refuses, and the next ``labels``
makes them whole (no Ray needed)."""

from __future__ import annotations

import json
import os
import shutil

import pytest
from click.testing import CliRunner

from cli_run import one_error
from labelled_plant import make_plant
from plantdreamer.cli import main
from plantdreamer.errors import InputError

pytest.importorskip("pycocotools")
LABELS = ["--split", "1,1,1", "--allow-empty-split"]


@pytest.fixture(scope="module")
def plants(tmp_path_factory):
    """A folder of two finished plants, no label files and no record yet."""
    root = tmp_path_factory.mktemp("ds")
    for seed in (1, 2):
        make_plant(root / "plants" / f"bean-{seed}", seed=seed, eval_views=1, resolution=48,
                   points=800)  # fmt: skip
    return root


def cli(*args):
    return CliRunner().invoke(main, [*map(str, args)])


def copy(plants, tmp_path):
    target = tmp_path / "ds"
    shutil.copytree(plants, target)
    return target


def top(folder):
    return sorted(p.name for p in folder.iterdir())


@pytest.mark.parametrize("name", ["gallery.png", "splits.json", "dataset.json", "coco"])
def test_a_users_file_in_a_folder_that_never_held_a_dataset_is_refused(plants, tmp_path, name):
    ds = copy(plants, tmp_path)
    mine = ds / name
    if name == "coco":
        mine.mkdir()
        mine = mine / "train.json"
    mine.write_text('{"mine": true}')
    before = top(ds)
    one_error(cli("labels", ds, *LABELS), "no dataset record")
    assert mine.read_text() == '{"mine": true}' and top(ds) == before


def test_dataset_dry_run_refuses_a_users_gallery(tmp_path):
    (tmp_path / "gallery.png").write_bytes(b"my gallery")
    result = cli("dataset", "--species", "bean", "--guidance", "none", "--dry-run",
                 "--allow-empty-split", "--out", tmp_path)  # fmt: skip
    one_error(result, "gallery.png")
    assert (tmp_path / "gallery.png").read_bytes() == b"my gallery"


def test_the_dataset_replaces_its_own_files_once_it_holds_its_record(plants, tmp_path):
    ds = copy(plants, tmp_path)
    assert cli("labels", ds, *LABELS).exit_code == 0
    record = json.loads((ds / "dataset.json").read_text())
    assert "card" in record and not (ds / "export.incomplete").exists()
    first = (ds / "splits.json").read_text()
    result = cli("labels", ds, "--split", "1,1,1", "--split-seed", 7, "--allow-empty-split")
    assert result.exit_code == 0, result.output
    assert json.loads((ds / "splits.json").read_text())["seed"] == 7 != json.loads(first)["seed"]


def test_a_swap_stopped_between_renames_is_marked_and_refused(plants, tmp_path, monkeypatch):
    from plantdreamer.data import PlantViews

    ds = copy(plants, tmp_path)
    assert cli("labels", ds, *LABELS).exit_code == 0
    assert len(PlantViews(ds)) == 2
    real_rename, moved = os.replace, []

    def stopping_rename(src, dst):  # stops after the marker, the card and splits.json
        if len(moved) == 4:
            raise KeyboardInterrupt
        if os.path.dirname(dst) == str(ds):
            moved.append(dst)
        real_rename(src, dst)

    monkeypatch.setattr(os, "rename", stopping_rename)
    monkeypatch.setattr(os, "replace", stopping_rename)
    result = cli("labels", ds, "--split", "1,1,1", "--split-seed", 7, "--allow-empty-split")
    monkeypatch.undo()
    assert result.exit_code != 0 and [os.path.basename(m) for m in moved] == [
        "export.incomplete", "README.md", "dataset.json", "splits.json"]  # fmt: skip
    # a mix: the new splits beside the earlier COCO files, and the folder says so
    assert json.loads((ds / "splits.json").read_text())["seed"] == 7
    assert (ds / "export.incomplete").is_file()
    with pytest.raises(InputError, match="plantdreamer labels"):
        PlantViews(ds)
    result = cli("labels", ds, *LABELS)
    assert result.exit_code == 0, result.output
    assert not (ds / "export.incomplete").exists() and len(PlantViews(ds)) == 2
    assert not [p for p in ds.iterdir() if p.name.startswith(".staging")]
