"""The Python API (``plantdreamer.generate``, ``plantdreamer.make_dataset``) and the examples
in examples/: each script runs as a user runs it, with its own tiny settings, and the
notebook runs in a Jupyter kernel. The dataset example joins the shared Ray instance, so it
is tested in test_dataset_ray.py."""

from __future__ import annotations

import inspect
import json
import os
import runpy
import sys
from pathlib import Path

import pytest

import plantdreamer
from plantdreamer import settings
from plantdreamer.errors import InputError
from plantdreamer.pipeline.settings.config import GenerateConfig

EXAMPLES = Path(__file__).parents[1] / "examples"


def run_example(name: str, *args: object) -> None:
    """Runs examples/NAME as ``python examples/NAME ARGS`` would, in this process."""
    argv = sys.argv
    sys.argv = [str(EXAMPLES / name), *map(str, args)]
    try:
        runpy.run_path(str(EXAMPLES / name), run_name="__main__")
    finally:
        sys.argv = argv


@pytest.fixture(scope="module")
def example_plant(tmp_path_factory):
    """The plant examples/generate_plant.py makes, and what it printed."""
    import contextlib
    import io

    out = tmp_path_factory.mktemp("example") / "bean"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        run_example("generate_plant.py", out)
    return out, printed.getvalue()


def test_the_generate_example_makes_a_plant_and_says_where_it_is(example_plant):
    out, printed = example_plant
    assert f"{out / 'plant.ply'}: " in printed
    assert len(list((out / "renders").glob("view_*.png"))) == 4
    assert f"progress pictures: {out / 'progress.png'}" in printed
    assert "loss plot: none (no guidance)" in printed and not (out / "loss.png").exists()
    from PIL import Image

    with Image.open(out / "progress.png") as strip:  # steps 2: the final checkpoint's picture
        assert strip.size == (128, 128 + 14)
    assert json.loads((out / "run.json").read_text())["config"]["eval-views"] == 4


def test_the_browse_example_draws_a_view_of_a_plant_folder(example_plant, tmp_path, capsys):
    out, _ = example_plant
    run_example("browse_dataset.py", out, tmp_path / "browse.png")
    printed = capsys.readouterr().out
    assert "4 views; classes {1: 'leaf', 2: 'stem', 3: 'pot', 4: 'soil'}" in printed
    assert (tmp_path / "browse.png").read_bytes().startswith(b"\x89PNG")


@pytest.mark.slow  # two plants generated: about 15 s of CPU
def test_the_leaf_counting_example_reads_each_views_count(tmp_path, capsys):
    import csv

    run_example("leaf_counting.py", tmp_path / "set")
    printed = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0] for line in printed] == ["kale-g0.5", "kale-g1"]
    totals = []
    for line, name in zip(printed, ("kale-g0.5", "kale-g1"), strict=True):
        folder = tmp_path / "set" / name
        traits = json.loads((folder / "traits.json").read_text())
        with open(folder / "counts.csv", newline="") as f:
            views = list(csv.DictReader(f))
        assert len(views) == 2 and f"{traits['plant']['leaf_count']} leaves" in line
        for view in views:
            assert f"{view['file_name']}: {view['leaf_count']}" in line
            assert 0 < int(view["leaf_count"]) <= traits["plant"]["leaf_count"]
        totals.append(traits["plant"]["leaf_count"])
    assert totals[0] < totals[1]  # the younger kale has fewer leaves


@pytest.mark.slow
def test_the_quickstart_notebook_runs(tmp_path):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    notebook = nbformat.read(EXAMPLES / "quickstart.ipynb", as_version=4)
    env = {"PLANTDREAMER_EXAMPLE_OUT": str(tmp_path / "plant")}
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)  # the kernel inherits this process's environment
    try:
        nbclient.NotebookClient(
            notebook, timeout=120, resources={"metadata": {"path": tmp_path}}
        ).execute()
    finally:
        for k, v in old.items():
            os.environ.pop(k) if v is None else os.environ.__setitem__(k, v)
    outputs = [o for cell in notebook.cells if cell.cell_type == "code" for o in cell.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    text = "".join(o.get("text", "") for o in outputs)
    assert "4 views; classes {1: 'leaf', 2: 'stem', 3: 'pot', 4: 'soil'}" in text
    assert sum("image/png" in o.get("data", {}) for o in outputs) == 2  # progress, a render
    assert (tmp_path / "plant" / "plant.ply").is_file()


def test_the_api_takes_every_setting_by_its_one_name_with_its_default():
    names = {s.param: s for s in settings.walk(GenerateConfig)}
    for function, per_plant in ((plantdreamer.generate, set()),
                                (plantdreamer.make_dataset, {"seed"})):  # fmt: skip
        params = inspect.signature(function).parameters
        for param, s in names.items():
            if param in per_plant:
                assert param not in params, param
                continue
            if function is plantdreamer.make_dataset and param in ("species", "pointcloud"):
                continue  # also the dataset's own options (a group per species or cloud)
            assert params[param].default == s.default, param
            assert params[param].kind is inspect.Parameter.KEYWORD_ONLY, param
            assert f"``{param}`` = {s.default!r}: " in function.__doc__, param


def test_make_dataset_takes_the_options_of_the_dataset_command():
    from plantdreamer.cli.dataset import dataset

    params = set(inspect.signature(plantdreamer.make_dataset).parameters)
    # The command's own names for what the API names plainly: --out, SPEC_FILE, --split,
    # --resource, --scenes; --set NAME=VALUE is any keyword; --dry-run prints a plan (command
    # only).
    renamed = {"out_dir": "out", "spec_file": "spec", "split_ratios": "split",
               "scene_seeds": "scenes"}  # fmt: skip
    for option in dataset.params:
        if option.name in ("settings", "dry_run", "help"):
            continue
        if option.name in ("count", "seed_start"):  # the command's earlier --seeds (hidden)
            assert option.hidden and option.name not in params, option.name
            continue
        assert renamed.get(option.name, option.name) in params, option.name


def test_the_api_refuses_a_wrong_setting_before_any_run(tmp_path):
    with pytest.raises(InputError, match="unknown setting 'pointz'; did you mean 'points'"):
        plantdreamer.generate(tmp_path / "p", species="bean", pointz=10)
    with pytest.raises(InputError, match="resume continues with the settings it started with"):
        plantdreamer.generate(tmp_path / "p", resume=True, points=10)
    with pytest.raises(InputError, match="give a spec, species or pointcloud"):
        plantdreamer.make_dataset(tmp_path / "d", steps=2)
    assert not (tmp_path / "p").exists() and not (tmp_path / "d").exists()
