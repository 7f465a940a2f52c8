"""The Python API checks its arguments as the command line does (one routine below both:
``dataset.request``, ``pipeline.requested``), answers in Python's words, returns one type
with absolute paths, and raises errors importable from ``plantdreamer``. Nothing here
trains: the run itself is replaced where a test reaches it."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from click.testing import CliRunner

import plantdreamer
from plantdreamer.api.words import in_python_words
from plantdreamer.cli import main
from plantdreamer.errors import InputError

NO_GUIDANCE = {"species": "bean", "guidance": "none"}


class Reached(Exception):
    """The run was reached, with these options (the call's checks all passed)."""


@pytest.fixture
def captured(monkeypatch):
    """What ``run_dataset`` would get, from the command line and from the API."""
    import plantdreamer.dataset as dataset

    calls = []

    def capture(spec, plants, out, options):
        calls.append((spec, [p.config for p in plants], options))
        raise Reached

    monkeypatch.setattr(dataset, "run_dataset", capture)
    return calls


def cli(*args):
    return CliRunner().invoke(main, ["dataset", *map(str, args)])


# (API keyword arguments, the same on the command line): each pair reaches the run with
# the same options, or both are refused.
SAME = [
    ({"split": (1, 1, 2)}, ["--split", "1,1,2"]),
    ({"split": "8,1,1", "split_seed": 3}, ["--split", "8,1,1", "--split-seed", "3"]),
    ({"max_retries": 0, "local_cpus": 1}, ["--max-retries", "0", "--local-cpus", "1"]),
    ({"cpus_per_plant": 1.5, "gpus_per_plant": 0},
     ["--cpus-per-plant", "1.5", "--gpus-per-plant", "0"]),
    ({"stuff": ["pot", "soil"], "min_instance_area": 4},
     ["--stuff", "pot,soil", "--min-instance-area", "4"]),
    ({"allow_empty_split": True, "redo_changed": True},
     ["--allow-empty-split", "--redo-changed"]),
    ({"seeds": [2, 3, 5]}, ["--seeds", "2-3,5"]),
    ({"steps": 4, "eval_views": 2}, ["--steps", "4", "--eval-views", "2"]),
]  # fmt: skip


@pytest.mark.parametrize(("kwargs", "args"), SAME)
def test_the_api_and_the_command_line_reach_the_run_with_the_same_options(
    tmp_path, captured, kwargs, args
):
    with pytest.raises(Reached):
        plantdreamer.make_dataset(tmp_path / "api", **NO_GUIDANCE, quiet=True, **kwargs)
    result = cli("--species", "bean", "--guidance", "none", "--quiet", *args,
                 "--out", tmp_path / "cli")  # fmt: skip
    assert "Reached" in result.output and len(captured) == 2, result.output  # the stand-in
    (_, api_configs, api_options), (_, cli_configs, cli_options) = captured
    assert api_options == cli_options and api_configs == cli_configs
    assert api_options.labels.ratios == pytest.approx(cli_options.labels.ratios)


def test_a_split_of_three_numbers_is_normalised_as_its_text_is(tmp_path, captured):
    with pytest.raises(Reached):
        plantdreamer.make_dataset(tmp_path, **NO_GUIDANCE, split=(1, 1, 2))
    assert captured[0][2].labels.ratios == (0.25, 0.25, 0.5)  # not every plant in train


# (API keyword arguments, command-line arguments or None where the command line cannot say
# it, the API's message): refused by both, before the run.
REFUSED = [
    ({"max_retries": -1}, ["--max-retries", "-1"], "max_retries must be >= 0, got -1"),
    ({"max_retries": 1.5}, ["--max-retries", "1.5"], "max_retries must be an integer"),
    ({"local_cpus": 0}, ["--local-cpus", "0"], "local_cpus must be >= 1"),
    ({"split": (1, -1, 2)}, ["--split", "1,-1,2"], "split must be TRAIN,VAL,TEST"),
    ({"split": (1, 1)}, ["--split", "1,1"], "split must be TRAIN,VAL,TEST"),
    ({"split": (0, 0, 0)}, ["--split", "0,0,0"], "split needs a positive weight"),
    ({"split_seed": -1}, ["--split-seed", "-1"], "split_seed must be >= 0"),
    ({"min_instance_area": 0}, ["--min-instance-area", "0"], "min_instance_area must be >= 1"),
    ({"cpus_per_plant": float("nan")}, ["--cpus-per-plant", "nan"], "cpus_per_plant must be"),
    ({"gpus_per_plant": -1}, ["--gpus-per-plant", "-1"], "gpus_per_plant must be >= 0"),
    ({"seeds": "3-1"}, ["--seeds", "3-1"], "seeds: 3-1 is a reversed range"),
    ({"seeds": [1, 1]}, ["--seeds", "1,1"], "distinct seeds"),
    ({"resources": {"CPU": 1}}, ["--resource", "CPU=1"], "use cpus_per_plant for CPU"),
    ({"redo_changed": "no"}, None, "redo_changed must be True or False, got 'no'"),
    ({"allow_empty_split": 1}, None, "allow_empty_split must be True or False"),
    ({"quiet": "yes"}, None, "quiet must be True or False"),
    ({"cpus_per_plant": True}, None, "cpus_per_plant must be a number"),
    ({"seeds": [0.5]}, None, "seeds must be text like '0-7' or integers"),
    ({"seeds": [True]}, None, "seeds must be text like '0-7' or integers"),
    ({"stuff": [1]}, None, "stuff must be names"),
    ({"resources": {"slot": True}}, None, "the amount must be a number"),
]


@pytest.mark.parametrize(("kwargs", "args", "message"), REFUSED)
def test_what_the_command_line_refuses_the_api_refuses_in_its_own_words(
    tmp_path, captured, kwargs, args, message
):
    with pytest.raises(InputError) as refused:
        plantdreamer.make_dataset(tmp_path / "api", **{**NO_GUIDANCE, **kwargs})
    assert message in str(refused.value) and "--" not in str(refused.value)
    if args is not None:
        result = cli("--species", "bean", "--guidance", "none", *args, "--out", tmp_path / "cli")
        assert result.exit_code in (1, 2) and "Traceback" not in result.output, result.output
    assert captured == [] and not (tmp_path / "api").exists()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"overwrite": "no"}, "overwrite must be True or False, got 'no'"),
        ({"resume": 1}, "resume must be True or False"),
        ({"quiet": None}, "quiet must be True or False"),
        ({"seeds": [0, 0.5]}, "seeds must be text like '0-7' or integers"),
        ({"seeds": "0-2", "seed": 3}, "give seed or seeds, not both"),
        ({"species": "beam"}, "did you mean 'bean'?"),
        ({"device": "banana"}, "unknown device 'banana'"),
        ({"points": "5"}, "points must be an integer"),
    ],
)
def test_generate_refuses_flags_and_settings_that_are_not_what_they_say(
    tmp_path, run_stand_in, kwargs, message
):
    run_stand_in(lambda *a, **k: pytest.fail("it ran"))
    with pytest.raises(InputError, match=message):
        plantdreamer.generate(tmp_path / "p", **{"species": "bean", **kwargs})
    assert not (tmp_path / "p").exists()


@pytest.fixture
def run_stand_in(monkeypatch):
    """Puts a stand-in for the pipeline's one entry (``pipeline.runs.entry.generate_plants``)
    where the API imports it from (the module itself, with torch, is not imported)."""
    import sys
    import types

    def install(function):
        module = types.ModuleType("plantdreamer.pipeline.runs.entry")
        module.generate_plants = function
        monkeypatch.setitem(sys.modules, "plantdreamer.pipeline.runs.entry", module)

    return install


class FakeResult:
    """What the entry returns for a finished plant (``PlantResult``'s fields the API reads)."""

    def __init__(self, folder):
        self.name, self.folder, self.ply_path = Path(folder).name, folder, f"{folder}/plant.ply"
        self.done, self.status, self.error = True, "done", None
        self.steps, self.gaussians, self.timings = 2, 10, {"prepare": 0.1}


@pytest.mark.parametrize("seeds", [None, "0-1"])
def test_generate_returns_a_list_of_plants_with_absolute_paths(
    tmp_path, monkeypatch, run_stand_in, seeds
):
    given = {}

    def fake(cfgs, out, **kwargs):
        given.update(out=out, cfgs=cfgs, **kwargs)
        return [FakeResult("rel/bean-s0000"), FakeResult("rel/bean-s0001")][: len(cfgs)]

    run_stand_in(fake)
    monkeypatch.chdir(tmp_path)
    made = plantdreamer.generate("out", seeds=seeds, **NO_GUIDANCE)
    assert isinstance(made, list) and len(made) == (1 if seeds is None else 2)
    assert all(isinstance(p, plantdreamer.GeneratedPlant) for p in made)
    from plantdreamer.pipeline import FolderPerPlant

    grouped = isinstance(given["layout"], FolderPerPlant)
    assert given["out"] == tmp_path / "out" and grouped is (seeds is not None)
    for plant in made:
        assert plant.folder.is_absolute() and plant.ply.is_absolute()
        assert plant.folder == tmp_path / "rel" / plant.folder.name


def test_a_refusal_below_the_api_names_its_keywords(tmp_path):
    """A dataset of other settings in the folder: the plan below the API refuses to remake
    it in the command line's words; the caller reads ``redo_changed=True``."""
    from plantdreamer.dataset import expand
    from plantdreamer.dataset.manifest import Manifest

    spec = {"group": [{"species": "bean", "seeds": "0-1"}], "defaults": {"guidance": "none"}}
    manifest = Manifest(tmp_path)
    for plant in expand(spec):  # finished, as an earlier run left them
        folder = tmp_path / "plants" / plant.id
        folder.mkdir(parents=True)
        for name in ("plant.ply", "run.json"):
            (folder / name).write_text(name)
        manifest.replace(plant.id, {"status": "done", "config_hash": plant.config_hash})
    with pytest.raises(InputError) as refused:
        plantdreamer.make_dataset(tmp_path, **NO_GUIDANCE, seeds="0-1", steps=7, quiet=True,
                                  allow_empty_split=True)  # fmt: skip
    message = str(refused.value)
    outside_commands = re.sub(r"`[^`]*`", "", message)
    assert "pass redo_changed=True to do so" in message and "--" not in outside_commands, message
    assert "`plantdreamer dataset --dry-run` lists the plan" in message


@pytest.mark.parametrize(
    ("message", "words"),
    [
        ("X holds a checkpoint; continue it with --resume /a/b, pass --overwrite to start "
         "afresh", "X holds a checkpoint; continue it with resume=True, pass overwrite=True to "
         "start afresh"),
        ("--resume continues /a with its settings (another --out, or --overwrite)",
         "resume=True continues /a with its settings (another out, or overwrite=True)"),
        ("change --split or --split-seed, or pass --allow-empty-split",
         "change split or split_seed, or pass allow_empty_split=True"),
        ("--set species=bean disagrees; --eval-views must be", "species=bean disagrees; "
         "eval_views must be"),
        ("train one with `plantdreamer lora train --out x`; see --help",
         "train one with `plantdreamer lora train --out x`; see --help"),
        ("(--dry-run lists the plan)", "(`plantdreamer dataset --dry-run` lists the plan)"),
        ("a file /tmp/my--file and a-b--c", "a file /tmp/my--file and a-b--c"),
    ],
)  # fmt: skip
def test_python_words_name_the_keywords_and_leave_commands_alone(message, words):
    assert in_python_words(message) == words


def test_every_error_the_api_documents_is_importable_from_the_package():
    import plantdreamer.errors

    assert plantdreamer.RunInterrupted is plantdreamer.errors.RunInterrupted  # the trainer's
    for name in ("PlantDreamerError", "InputError", "ModelNotFoundError", "CheckpointError",
                 "PlyError", "PlyWarning", "RunInterrupted", "PlantsFailed", "DatasetStopped"):  # fmt: skip
        assert name in plantdreamer.__all__ and hasattr(plantdreamer, name), name
    assert issubclass(plantdreamer.RunInterrupted, KeyboardInterrupt)
    assert issubclass(plantdreamer.PlantsFailed, plantdreamer.PlantDreamerError)
    assert "RunInterrupted" in plantdreamer.generate.__doc__
