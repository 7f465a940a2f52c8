"""The plantdreamer command: help, version, and one-line errors."""

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
