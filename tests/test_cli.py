"""The plantdreamer command: help, version, and one-line errors."""

import dataclasses
import subprocess
import sys

from click.testing import CliRunner

import plantdreamer
from plantdreamer.cli import COMMANDS, main


def test_help_lists_every_registered_command():
    result = CliRunner().invoke(main, ["--help"])
    assert result.exit_code == 0
    for name in COMMANDS:
        assert name in result.output


def test_version():
    result = CliRunner().invoke(main, ["--version"])
    assert result.exit_code == 0
    assert plantdreamer.__version__ in result.output


def test_unknown_command_fails():
    result = CliRunner().invoke(main, ["frobnicate"])
    assert result.exit_code != 0
    assert "No such command" in result.output


def test_info_runs_as_installed_console_script():
    out = subprocess.run(
        [sys.executable, "-m", "plantdreamer", "info"], capture_output=True, text=True, check=True
    ).stdout
    assert "native core" in out
    assert "cpu threads" in out


def test_help_does_not_import_torch():
    # Keeps `plantdreamer --help` instant: subcommands import heavy modules lazily.
    code = (
        "import sys; from click.testing import CliRunner; from plantdreamer.cli import main;"
        "CliRunner().invoke(main, ['--help']); print('torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def _commands(command, path=()):
    """Every command under ``command`` (subcommands of groups included), by its path."""
    import click

    ctx = click.Context(command)
    if isinstance(command, click.Group):
        for name in command.list_commands(ctx):
            yield from _commands(command.get_command(ctx, name), (*path, name))
    else:
        yield " ".join(path), command


def test_every_option_of_every_command_has_help_text():
    import click

    bare = [
        f"{name} {'/'.join(p.opts)}"
        for name, command in _commands(main)
        for p in command.params
        if isinstance(p, click.Option) and not p.hidden and not p.help
    ]
    assert bare == []


def test_generate_help_lists_its_options_by_section_then_examples():
    from plantdreamer.cli.help_sections import SECTION_TITLES
    from plantdreamer.pipeline.config import GenerateConfig

    result = CliRunner().invoke(main, ["generate", "--help"])
    assert result.exit_code == 0
    headings = [line[:-1] for line in result.output.splitlines()
                if line.endswith(":") and not line.startswith(" ")]  # fmt: skip
    # Every section of the config has its heading, in the config's order; nothing is left
    # under a catch-all heading.
    sections = [f.name for f in dataclasses.fields(GenerateConfig) if f.name in SECTION_TITLES]
    assert headings == [SECTION_TITLES[""], *(SECTION_TITLES[s] for s in sections)]
    assert "\n  Examples:\n" in result.output
    text = result.output
    assert text.index("--points") < text.index("Initial Gaussians:") < text.index("--sh-degree ")
    assert text.index("--eval-views") > text.index("Outputs:")
    assert text.index("--resume") < text.index("Input: species")  # the run's own options
    assert "  plantdreamer generate --resume bean" in text


def test_info_check_says_what_is_present_and_fails_on_a_missing_lora(tmp_path):
    from plantdreamer.guidance.lora_weights import LORA_WEIGHT_NAME

    lora = tmp_path / "bean"
    lora.mkdir()
    (lora / LORA_WEIGHT_NAME).write_bytes(b"")
    base = tmp_path / "base"
    base.mkdir()
    args = ["info", "--check", "--base-model", str(base), "--lora", str(lora)]
    result = CliRunner().invoke(main, args)
    rows = {
        line[: line.index("  ")].strip(): line[line.index("  ") :].strip()
        for line in result.output.splitlines()
    }
    assert rows["base model"].startswith(f"incomplete: folder {base} lacks unet/config.json")
    assert rows[f"LoRA {lora}"] == f"present: {lora / LORA_WEIGHT_NAME}"
    assert "extra [cluster]" in rows and "extra [dev]" not in rows
    assert result.exit_code == 1  # a model is missing
    result = CliRunner().invoke(main, ["info", "--check", "--lora", str(tmp_path / "nothere")])
    assert f"LoRA {tmp_path / 'nothere'}" in result.output and "missing: LoRA" in result.output
    assert result.exit_code == 1
