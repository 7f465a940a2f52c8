"""The plantdreamer command: help, version, and one-line errors."""

import subprocess
import sys
from pathlib import Path

import click
from click.testing import CliRunner

import plantdreamer
from plantdreamer import cli
from plantdreamer.cli import COMMANDS, main
from plantdreamer.dataset.spec import tomllib


def test_help_lists_every_registered_command():
    result = CliRunner().invoke(main, ["--help"])
    assert result.exit_code == 0
    for name in COMMANDS:
        assert name in result.output


@click.command()
def _boom() -> None:
    raise RuntimeError("a bug")


def test_help_and_internal_errors_point_at_the_documentation(monkeypatch):
    # The URLs a wheel user has: the same as the wheel's metadata (pyproject.toml).
    pyproject = Path(__file__).resolve().parent.parent / "pyproject.toml"
    urls = tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"]["urls"]
    assert (urls["Documentation"], urls["Issues"]) == (cli.DOCS_URL, cli.ISSUES_URL)
    assert cli.DOCS_URL in CliRunner().invoke(main, ["--help"]).output

    monkeypatch.setitem(COMMANDS, "boom", f"{__name__}:_boom")
    monkeypatch.delenv("PLANTDREAMER_TRACEBACK", raising=False)
    result = CliRunner().invoke(main, ["boom"])
    assert result.exit_code == 1 and "internal error" in result.output
    assert cli.ISSUES_URL in result.output and cli.DOCS_URL in result.output


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
