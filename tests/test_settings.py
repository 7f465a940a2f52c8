"""One source of truth for settings: the config dataclasses drive the CLI, run.json and
checkpoints, and a run never changes its caller's config."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from plantdreamer.cli import generate as generate_cli
from plantdreamer.cli.options import config_from_options
from plantdreamer.errors import CheckpointError
from plantdreamer.guidance.config import SCHEDULES, SDS_DEFAULTS, SdsConfig
from plantdreamer.guidance.schedules import BUILTIN_SCHEDULES
from plantdreamer.pipeline import GenerateConfig, generate_plants
from plantdreamer.pipeline.model.density import CullConfig
from plantdreamer.pipeline.model.source import SourceConfig
from plantdreamer.pipeline.outputs import OutputsConfig
from plantdreamer.pipeline.settings.train_config import TrainConfig
from plantdreamer.pipeline.state.checkpoint import CheckpointRecord


def patch_default(monkeypatch, cls, name, value):
    """Changes a section's default as an edit of its source would: the field and __init__."""
    monkeypatch.setattr(cls.__dataclass_fields__[name], "default", value)
    defaults = list(cls.__init__.__defaults__)
    missing = dataclasses.MISSING
    with_default = [
        f.name
        for f in dataclasses.fields(cls)
        if f.default is not missing or f.default_factory is not missing
    ]
    defaults[with_default.index(name)] = value
    monkeypatch.setattr(cls.__init__, "__defaults__", tuple(defaults))


def test_a_changed_section_default_changes_help_spec_and_behaviour(monkeypatch, tmp_path):
    from plantdreamer.dataset.spec import expand

    patch_default(monkeypatch, TrainConfig, "steps", 0)
    patch_default(monkeypatch, OutputsConfig, "eval_views", 2)
    patch_default(monkeypatch, CullConfig, "threshold", 2.5)
    patch_default(monkeypatch, SdsConfig, "guidance_scale", 7.5)
    command = generate_cli.build_command()
    help_text = CliRunner().invoke(command, ["--help"], terminal_width=200).output
    assert "Optimisation steps.  [default: 0]" in help_text
    assert "Renders on the evaluation orbit.  [default: 2;" in help_text
    assert "C in V > mean + C std.  [default: 2.5]" in help_text
    assert "Classifier-free guidance scale.  [default: 7.5]" in help_text

    (plant,) = expand({"group": [{"species": "bean"}]})
    assert plant.config.get("cull-threshold") == 2.5 and plant.config.get("eval-views") == 2

    out = tmp_path / "o"
    args = ["--species", "bean", "--guidance", "none", "--points", "1500", "--resolution", "48"]
    result = CliRunner().invoke(command, [*args, "--out", str(out), "--quiet"])
    assert result.exit_code == 0, result.output
    config = json.loads((out / "run.json").read_text())["config"]
    assert config["steps"] == 0 and config["eval-views"] == 2  # saved by their names
    assert config["cull-threshold"] == 2.5
    assert config["guidance-scale"] == 7.5
    assert len(list((out / "renders").iterdir())) == 2


def test_every_setting_has_its_dataclass_default_on_the_command_line():
    command = generate_cli.build_command()
    defaults = {p.name: p.default for p in command.params}
    built = config_from_options(GenerateConfig, dict(defaults))
    assert built == GenerateConfig()
    assert defaults["cull_threshold"] == CullConfig().threshold
    assert defaults["sds_resolution"] == SDS_DEFAULTS.resolution


def _other_value(name, value, cfg):
    """A valid value of setting ``name`` that differs from ``value``."""
    import typing

    from plantdreamer import settings

    s = settings.by_name(GenerateConfig)[name]
    choices = s.field.metadata.get(settings.CHOICES)
    if choices:
        return next(c for c in choices if c != value)
    if isinstance(value, bool):
        return not value
    if isinstance(value, tuple):
        return (value[0] + 0.5, value[1] + 1.0)
    if settings.RANGE in s.field.metadata:  # another value inside the range
        low, high = s.field.metadata[settings.RANGE]
        inside = [
            v for v in (high, low, (low + high) / 2) if settings.in_range(v, s.field.metadata)
        ]
        return next(v for v in inside if v != value)
    if value is None:
        kinds = [a for a in typing.get_args(s.type) if a is not type(None)]
        if typing.get_origin(kinds[0]) is tuple:  # a range or a colour left open
            return (0.25, 0.5, 0.75)[: len(typing.get_args(kinds[0]))]
        return {int: 16, float: 0.5, str: "{species} leaves"}[kinds[0]]
    if isinstance(value, int):
        return value + 1
    if isinstance(value, float):
        return value * 0.5
    return value + "x"


EXEMPT = {"pointcloud", "seed", "species"}  # chosen per plant in a spec


def _views_inputs(tmp_path):
    """Files the views' settings name (a real rig, a folder of backgrounds), and the other
    settings some need beside them (a range is a drawn rig's)."""
    import imageio.v3 as iio

    rig = tmp_path / "rig.json"
    rig.write_text(json.dumps({"fl_x": 20, "fl_y": 20, "cx": 16, "cy": 16, "w": 32, "h": 32,
                               "frames": [{"file_path": "a.png", "transform_matrix": [
                                   [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 3], [0, 0, 0, 1]]}]}))  # fmt: skip
    (tmp_path / "photos").mkdir()
    iio.imwrite(tmp_path / "photos" / "bench.png", np.zeros((8, 8, 3), np.uint8))
    values = {"rig-transforms": str(rig), "background-images": str(tmp_path / "photos")}
    drawn = ("elevation-deg", "azimuth-deg", "distance", "roll-deg", "fovy-deg", "width", "height")
    companions = {f"rig-{n}": {"rig": "random"} for n in drawn}
    companions["rig-transforms"] = {"rig": "transforms"}
    return values, companions


def test_every_setting_has_one_name_on_the_cli_in_a_spec_in_set_and_on_resume(tmp_path):
    """Each setting's CLI option name is its key in a spec, in `dataset --set` and in the
    changes `--resume` checks: the same name reaches the same field everywhere."""
    from plantdreamer.cli.dataset import _toml_value
    from plantdreamer.dataset.spec import expand
    from plantdreamer.pipeline.runs.start import resumed_config

    base = GenerateConfig.of(species="bean")
    command = generate_cli.build_command()
    inputs, companions = _views_inputs(tmp_path)
    for name, value in base.settings().items():
        new = inputs.get(name, _other_value(name, value, base))
        if name in ("prompt-template", "negative-prompt", "schedule", "device"):
            new = {"prompt-template": "{species} leaves", "negative-prompt": "blurry",
                   "schedule": "released", "device": "cpu"}[name]  # fmt: skip
        text = json.dumps(list(new) if isinstance(new, tuple) else new)
        # The command line.
        cli_args = [f"--{name}", *map(str, new)] if isinstance(new, tuple) else (
            [f"--{name}" if new else f"--no-{name}"] if isinstance(new, bool)
            else [f"--{name}", str(new)]
        )  # fmt: skip
        ctx = command.make_context("generate", list(cli_args))
        assert ctx.params[name.replace("-", "_")] == new, name
        if name in EXEMPT:
            continue
        # A spec and `dataset --set NAME=VALUE` (its values are TOML).
        defaults = {**companions.get(name, {}), name: _toml_value(text)}
        spec = {"defaults": defaults, "group": [{"species": "bean"}]}
        (plant,) = expand(spec)
        assert plant.config.get(name) == new, name
        # A resume given the setting again: refused by name (only steps may change).
        if name != "steps":
            with pytest.raises(CheckpointError, match=f"{name}: checkpoint"):
                resumed_config(base, 0, {name: new}, tmp_path)
        assert resumed_config(base, 0, {name: value}, tmp_path)[1] is None


def test_an_unknown_or_old_setting_name_says_which_one_is_meant():
    from plantdreamer.dataset.spec import expand
    from plantdreamer.errors import InputError

    with pytest.raises(InputError, match="unknown setting 'n-points'; did you mean 'points'"):
        expand({"defaults": {"n_points": 10}, "group": [{"species": "bean"}]})


def test_config_round_trips_with_nested_settings():
    cfg = GenerateConfig.of(
        species="bean",
        densify_until=700,
        densify_grad_threshold=1e-4,
        cull_threshold=2.0,
        cameras_distance=(2.0, 5.0),
        schedule="released",
    )
    assert cfg.density.densify.until == 700 and cfg.train.cameras.distance == (2.0, 5.0)
    data = json.loads(json.dumps(cfg.to_dict()))
    assert GenerateConfig.from_dict(data) == cfg


def test_generate_does_not_change_the_callers_config(tmp_path):
    cfg = GenerateConfig.of(
        species="kale", points=1500, eval_views=1, turntable_frames=1, steps=0, guidance="none"
    )
    before = GenerateConfig.from_dict(cfg.to_dict())
    generate_plants([cfg], tmp_path, show_progress=False)
    assert cfg == before and cfg.train.resolution is None


def test_bad_choice_is_an_input_error():
    from plantdreamer.errors import InputError

    with pytest.raises(InputError, match="color init must be one of original, noise"):
        GenerateConfig.of(species="bean", color_init="red").validate()


def test_schedule_choices_are_the_built_in_schedules():
    assert set(SCHEDULES) == set(BUILTIN_SCHEDULES)


class _Stop(Exception):
    pass


def _stop_after(last):
    def hook(step):
        if step == last:
            raise _Stop

    return hook


def test_checkpoint_loads_without_running_code(tmp_path):
    """Checkpoints hold plain data only, so they load with weights_only=True."""
    from plantdreamer.guidance.base import PhotometricGuidance

    # Every value a run decides itself when left open is given (resolution, precision,
    # prompt, overlap).
    cfg = GenerateConfig.of(
        species="mint", points=1500, resolution=32, eval_views=1, turntable_frames=1,
        steps=3, checkpoint_every=2, network_dtype="float32", prompt_template="{species}",
        overlap="off",
    )  # fmt: skip
    guidance = PhotometricGuidance(torch.full((1, 32, 32, 3), 0.5))
    with pytest.raises(_Stop):
        generate_plants(
            [cfg], tmp_path, guidance=guidance, show_progress=False, on_step=_stop_after(1)
        )
    state = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    assert state["step"] == 2
    assert GenerateConfig.from_dict(state["config"]) == dataclasses.replace(cfg)


def test_a_finished_run_leaves_no_checkpoint(tmp_path):
    from plantdreamer.guidance.base import PhotometricGuidance

    cfg = GenerateConfig.of(
        species="mint", points=1500, resolution=32, eval_views=1, turntable_frames=1,
        steps=3, checkpoint_every=2,
    )  # fmt: skip
    guidance = PhotometricGuidance(torch.full((1, 32, 32, 3), 0.5))
    generate_plants([cfg], tmp_path, guidance=guidance, show_progress=False)
    assert (tmp_path / "run.json").is_file() and not (tmp_path / "checkpoint.pt").exists()


def test_records_save_each_setting_under_the_name_a_user_types():
    """run.json, group.json and checkpoints keep ``to_dict()``: one key per setting, the
    option's name without dashes (brush saves its flags' names)."""
    cfg = GenerateConfig.of(species="bean", densify_every=7, cameras_distance=(2.0, 5.0))
    saved = cfg.to_dict()
    options = {o for p in generate_cli.build_command().params for o in p.opts}
    assert {f"--{name}" for name in saved} <= options
    assert saved["densify-every"] == 7 and saved["cameras-distance"] == [2.0, 5.0]
    assert GenerateConfig.from_dict(json.loads(json.dumps(saved))) == cfg


OLD_RUN = Path(__file__).parent / "data" / "run_sections" / "run.json"
OLD_RUN_SETTINGS = dict(
    species="bean", seed=3, points=2000, resolution=64, eval_views=3, turntable="none",
    steps=4, guidance="none", densify_every=2,
)  # fmt: skip  # the command in data/run_sections/README.md


def test_a_run_json_of_the_sectioned_version_still_reads_resumes_and_renders(tmp_path):
    from plantdreamer.cli import main
    from plantdreamer.exports.listing import plant_species
    from plantdreamer.pipeline.runs.start import resumed_config
    from plantdreamer.pipeline.settings.config import from_record

    old = json.loads(OLD_RUN.read_text())
    assert old["config"]["density"]["densify"]["every"] == 2  # the sectioned form
    cfg = from_record(old["config"])
    assert {k: cfg.get(k) for k in OLD_RUN_SETTINGS} == OLD_RUN_SETTINGS
    assert plant_species(OLD_RUN) == "bean"
    # --resume reads a checkpoint's config through the same function.
    record = CheckpointRecord.from_saved({"config": old["config"], "step": 2}, tmp_path)
    resumed, note = resumed_config(record.config, record.step, {"steps": 6}, tmp_path)
    assert resumed.train.steps == 6 and note == {
        "step": 2, "event": "steps changed", "from": 4, "to": 6
    }  # fmt: skip
    # `render` of a plant folder takes the orbit of the run.json beside plant.ply.
    plant = tmp_path / "plant"
    generate_plants([GenerateConfig.of(**OLD_RUN_SETTINGS)], plant, show_progress=False)
    new = json.loads((plant / "run.json").read_text())
    # Every setting as resolved by that version, but the orbit's distance: 4.0 was then the
    # default; now none is set and generate frames the orbit on the plant.
    assert cfg.get("eval-distance") == 4.0 and new["config"]["eval-distance"] is None
    # The depth map's size: that version rendered it at the render size (RECORDED_BEFORE).
    assert cfg.get("depth-size") == "render" and new["config"]["depth-size"] == "sds"
    framed = from_record({**new["config"], "eval-distance": 4.0, "depth-size": "render"})
    assert framed == cfg
    assert "source" not in new["config"] and new["config"]["densify-every"] == 2
    (plant / "run.json").write_text(OLD_RUN.read_text())
    out = tmp_path / "renders"
    result = CliRunner().invoke(main, ["render", str(plant), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "wrote 3 views" in result.output  # eval-views 3 from the old record


@pytest.mark.parametrize(
    ("module", "command", "cls", "field", "name", "value"),
    [
        ("render", "render", OutputsConfig, "eval_elevation_deg", "eval_elevation_deg", 22.5),
        ("render", "render", OutputsConfig, "eval_views", "eval_views", 7),
        ("render", "render", TrainConfig, "background", "background", 0.5),
        ("prepare", "prepare", SourceConfig, "sor_std", "sor_std", 2.5),
        ("prepare", "prepare", SourceConfig, "points", "points", 1234),
        ("eval", "eval_command", TrainConfig, "background", "background", 0.5),
    ],
)
def test_render_prepare_and_eval_read_generates_declaration(
    monkeypatch, module, command, cls, field, name, value
):
    """One declaration per setting across commands: a default changed in generate's section
    is the default of the other command's option too (its --help and its run)."""
    import importlib

    mod = importlib.import_module(f"plantdreamer.cli.{module}")
    patch_default(monkeypatch, cls, field, value)
    try:
        other = getattr(importlib.reload(mod), command)
        defaults = {p.name: p.default for p in other.params}
        assert defaults[name] == value
        generate_defaults = {p.name: p.default for p in generate_cli.build_command().params}
        assert str(generate_defaults[name]) == str(value)
        help_text = " ".join(CliRunner().invoke(other, ["--help"]).output.split())
        assert f"[default: {value}]" in help_text or f"[default: {value};" in help_text
    finally:
        monkeypatch.undo()
        importlib.reload(mod)


def test_lora_train_options_are_its_config(monkeypatch):
    import importlib

    from plantdreamer.lora.config import LoraTrainConfig

    mod = importlib.import_module("plantdreamer.cli.lora")
    patch_default(monkeypatch, LoraTrainConfig, "rank", 8)
    try:
        command = importlib.reload(mod).train
        assert {p.name: p.default for p in command.params}["rank"] == 8
        assert LoraTrainConfig("photos").rank == 8  # the API's default, the same field
        assert "LoRA rank. [default: 8]" in " ".join(
            CliRunner().invoke(command, ["--help"]).output.split()
        )
    finally:
        monkeypatch.undo()
        importlib.reload(mod)


def test_a_record_without_a_later_setting_reads_as_the_version_that_wrote_it():
    from plantdreamer.pipeline.settings.config import RECORDED_BEFORE, from_record

    cfg = GenerateConfig.of(species="bean", seed=1)
    record = cfg.to_dict()
    assert from_record(record) == cfg  # a record with every setting reads as it is
    for name, then in RECORDED_BEFORE.items():
        assert cfg.get(name) != then  # today's default differs, or the entry is not needed
        older = {k: v for k, v in record.items() if k != name}
        assert from_record(older).get(name) == then
        assert from_record(older).settings() == {**cfg.settings(), name: then}
    assert GenerateConfig.from_dict(json.loads(json.dumps(record))) == cfg
