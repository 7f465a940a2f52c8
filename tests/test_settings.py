"""One source of truth for settings: the config dataclasses drive the CLI, run.json and
checkpoints, and a run never changes its caller's config."""

import dataclasses
import json

import pytest
import torch
from click.testing import CliRunner

from plantdreamer.cli import generate as generate_cli
from plantdreamer.cli.options import config_from_options
from plantdreamer.guidance.config import SCHEDULES, SDS_DEFAULTS
from plantdreamer.guidance.schedules import BUILTIN_SCHEDULES
from plantdreamer.pipeline import GenerateConfig, generate
from plantdreamer.pipeline.config import CullConfig, DensifyConfig


def patch_default(monkeypatch, cls, name, value):
    monkeypatch.setattr(cls.__dataclass_fields__[name], "default", value)


def test_a_changed_dataclass_default_changes_help_and_behaviour(monkeypatch, tmp_path):
    patch_default(monkeypatch, GenerateConfig, "steps", 0)
    patch_default(monkeypatch, GenerateConfig, "eval_views", 2)
    patch_default(monkeypatch, CullConfig, "threshold", 2.5)
    patch_default(monkeypatch, GenerateConfig, "guidance_scale", 7.5)
    command = generate_cli.build_command()
    help_text = CliRunner().invoke(command, ["--help"], terminal_width=200).output
    assert "Optimisation steps.  [default: 0]" in help_text
    assert "Renders on the evaluation orbit.  [default: 2]" in help_text
    assert "C in V > mean + C std.  [default: 2.5]" in help_text
    assert "Classifier-free guidance scale.  [default: 7.5]" in help_text

    out = tmp_path / "o"
    args = ["--species", "bean", "--guidance", "none", "--points", "1500", "--resolution", "48"]
    result = CliRunner().invoke(command, [*args, "--out", str(out), "--quiet"])
    assert result.exit_code == 0, result.output
    config = json.loads((out / "run.json").read_text())["config"]
    assert config["steps"] == 0 and config["eval_views"] == 2
    assert config["cull"]["threshold"] == 2.5 and config["guidance_scale"] == 7.5
    assert len(list((out / "renders").iterdir())) == 2


def test_every_setting_has_its_dataclass_default_on_the_command_line():
    command = generate_cli.build_command()
    defaults = {p.name: p.default for p in command.params}
    built = config_from_options(GenerateConfig, dict(defaults))
    assert built == GenerateConfig()
    assert defaults["cull__threshold"] == CullConfig().threshold
    assert defaults["sds_resolution"] == SDS_DEFAULTS.resolution


def test_config_round_trips_with_nested_settings():
    cfg = GenerateConfig(
        species="bean",
        densify=DensifyConfig(until=700, grad_threshold=1e-4),
        cull=CullConfig(threshold=2.0),
        schedule="released",
    )
    data = json.loads(json.dumps(cfg.to_dict()))
    assert GenerateConfig.from_dict(data) == cfg


def test_generate_does_not_change_the_callers_config(tmp_path):
    cfg = GenerateConfig(
        species="kale", n_points=1500, eval_views=1, turntable_frames=1, steps=0, guidance="none"
    )
    before = GenerateConfig.from_dict(cfg.to_dict())
    generate(cfg, tmp_path, show_progress=False)
    assert cfg == before and cfg.resolution is None


def test_bad_choice_is_an_input_error():
    from plantdreamer.errors import InputError

    with pytest.raises(InputError, match="color init must be one of original, noise"):
        GenerateConfig(species="bean", color_init="red").validate()


def test_schedule_choices_are_the_built_in_schedules():
    assert set(SCHEDULES) == set(BUILTIN_SCHEDULES)


def test_checkpoint_loads_without_running_code(tmp_path):
    """Checkpoints hold plain data only, so they load with weights_only=True."""
    from plantdreamer.guidance.base import PhotometricGuidance

    # Every value a run decides itself when left open is given (resolution, precision, prompt).
    cfg = GenerateConfig(
        species="mint", n_points=1500, resolution=32, eval_views=1, turntable_frames=1,
        steps=3, checkpoint_every=2, network_dtype="float32", prompt_template="{species}",
    )  # fmt: skip
    guidance = PhotometricGuidance(torch.full((1, 32, 32, 3), 0.5))
    generate(cfg, tmp_path, guidance=guidance, show_progress=False)
    state = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    assert state["step"] == 2
    assert GenerateConfig.from_dict(state["config"]) == dataclasses.replace(cfg)
