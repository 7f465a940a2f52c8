"""A ``dataset`` rerun with other settings never silently remakes finished plants, a dry run
shows the plan without starting any worker, ``species`` given as a setting is honoured or
refused, and a stopped run still prints its summary line. No worker or Ray starts here."""

import pytest
from click.testing import CliRunner

from cli_run import one_error
from plantdreamer.cli import main
from plantdreamer.dataset import RunOptions, expand, plan, run_dataset, runner
from plantdreamer.dataset.manifest import Manifest
from plantdreamer.errors import InputError
from plantdreamer.exports.dataset import LabelOptions

# A few plants: a split may draw none (the split check is tested in test_label_exports).
ANY_SPLIT = LabelOptions(allow_empty_split=True)
FAST = ["--guidance", "none", "--eval-views", "0", "--quiet", "--allow-empty-split"]


def invoke(*args):
    return CliRunner().invoke(main, ["dataset", *map(str, args)])


def finished(out, plants):
    """A dataset as an earlier run left it: every plant done, with its files."""
    manifest = Manifest(out)
    for plant in plants:
        folder = out / "plants" / plant.id
        folder.mkdir(parents=True)
        for name in ("plant.ply", "run.json", "checkpoint.pt"):
            (folder / name).write_text(f"{plant.id} {name}")
        manifest.replace(plant.id, {"status": "done", "config_hash": plant.config_hash})


def files(out):
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


@pytest.fixture
def no_ray(monkeypatch):
    def refuse(*_args):
        raise AssertionError("workers were started")

    monkeypatch.setattr(runner, "open_workers", refuse)


def spec_of(count, **defaults):
    """The spec that ``--species bean --count COUNT`` with FAST makes."""
    settings = {"guidance": "none", "eval-views": 0, **defaults}
    return {"group": [{"species": "bean", "count": count}], "defaults": settings}


def test_a_rerun_with_one_setting_changed_stops_with_a_count_and_deletes_nothing(tmp_path, no_ray):
    finished(tmp_path, expand(spec_of(3, steps=0)))
    before = files(tmp_path)
    result = invoke("--species", "bean", "--count", 3, *FAST, "--steps", 1, "--out", tmp_path)
    one_error(result, "3 finished plants")
    assert "--redo-changed" in result.output
    assert files(tmp_path) == before
    with pytest.raises(InputError, match="3 finished plants"):
        run_dataset(spec_of(3, steps=1), expand(spec_of(3, steps=1)), tmp_path,
                    RunOptions(show_progress=False, labels=ANY_SPLIT))  # fmt: skip
    assert files(tmp_path) == before


def test_redo_changed_on_the_command_line_lifts_the_refusal(tmp_path, monkeypatch):
    """The refusal asks for --redo-changed; given, the run plans the redo and goes on to
    start its workers."""
    from plantdreamer.errors import PlantDreamerError

    def reached(*_args):
        raise PlantDreamerError("reached the workers")

    monkeypatch.setattr(runner, "open_workers", reached)
    finished(tmp_path, expand(spec_of(2, steps=0)))
    args = ["--species", "bean", "--seeds", "0-1", *FAST, "--steps", 1, "--out", tmp_path]
    one_error(invoke(*args), "pass --redo-changed")
    one_error(invoke(*args, "--redo-changed"), "reached the workers")
    assert not (tmp_path / "plants" / "bean-s0000" / "plant.ply").exists()  # cleared for redo


def test_redo_changed_clears_them_and_a_new_plant_alone_is_no_redo(tmp_path):
    finished(tmp_path, expand(spec_of(2, steps=0)))
    grown = expand(spec_of(3, steps=0))  # one more plant, same settings: nothing to redo
    todo, skipped = plan.plan(grown, Manifest(tmp_path), tmp_path, 1)
    assert [p.id for p in todo] == ["bean-s0002"] and len(skipped) == 2
    changed = expand(spec_of(2, steps=1))
    todo, skipped = plan.plan(changed, Manifest(tmp_path), tmp_path, 1, redo_changed=True)
    assert len(todo) == 2 and not skipped
    assert not (tmp_path / "plants" / "bean-s0000").exists()


def test_dry_run_lists_the_plan_and_starts_nothing(tmp_path, no_ray):
    plants = expand(spec_of(4, steps=0))
    finished(tmp_path, plants[:2])
    # bean-s0002 was interrupted with its checkpoint: it resumes
    folder = tmp_path / "plants" / "bean-s0002"
    folder.mkdir()
    (folder / "checkpoint.pt").write_text("x")
    Manifest(tmp_path).replace("bean-s0002", {"status": "interrupted",
                                              "config_hash": plants[2].config_hash})  # fmt: skip
    before = files(tmp_path)
    result = invoke("--species", "bean", "--count", 4, *FAST, "--steps", 0, "--dry-run",
                    "--out", tmp_path)  # fmt: skip
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert "1 make, 1 resume, 2 skip, 0 redo" in lines[0], lines
    assert lines[1:] == ["skip    bean-s0000", "skip    bean-s0001", "resume  bean-s0002",
                         "make    bean-s0003"]  # fmt: skip
    result = invoke("--species", "bean", "--count", 4, *FAST, "--steps", 5, "--dry-run",
                    "--out", tmp_path)  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "2 make, 0 resume, 0 skip, 2 redo" in result.output
    assert "redo    bean-s0000" in result.output and "--redo-changed" in result.output
    assert files(tmp_path) == before
    fresh = tmp_path / "fresh"
    result = invoke("--species", "bean", *FAST, "--dry-run", "--out", fresh)
    assert result.exit_code == 0 and "make    bean-s0000" in result.output, result.output
    assert not fresh.exists()


def test_species_of_defaults_or_set_is_honoured(tmp_path):
    cloud = tmp_path / "scan.ply"
    cloud.write_text("not read by expand but its digest")
    spec = {"base_dir": str(tmp_path), "defaults": {"species": "kale", "guidance": "none"},
            "group": [{"pointclouds": "scan.ply"}, {"count": 1}]}  # fmt: skip
    scan, kale = expand(spec)
    assert scan.config.source.species == "kale" and scan.config.source.pointcloud
    assert kale.config.source.species == "kale" and kale.id == "kale-s0000"


def test_species_given_twice_and_differently_is_refused(tmp_path):
    result = invoke("--species", "kale", "--set", "species=bean", *FAST, "--out", tmp_path / "d")
    one_error(result, "species")
    assert not (tmp_path / "d").exists()
    assert invoke("--species", "kale", "--set", "species=kale", *FAST, "--dry-run", "--out",
                  tmp_path / "d").exit_code == 0  # fmt: skip


def test_a_stopped_run_prints_its_summary_line(tmp_path, monkeypatch):
    def sigterm_while_workers_start(*_args):
        raise KeyboardInterrupt

    monkeypatch.setattr(runner, "open_workers", sigterm_while_workers_start)
    finished(tmp_path, expand(spec_of(1, steps=0)))
    result = invoke("--species", "bean", "--count", 2, *FAST, "--steps", 0, "--out", tmp_path)
    assert result.exit_code == 130, result.output
    assert "stopped: 0 plants interrupted" in result.output, result.output
    assert "1 skipped" in result.output and "run the same command again" in result.output
