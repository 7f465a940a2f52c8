"""The command line as the tests call it: ``run(*args)`` (arguments as strings), and
``one_error``, which holds a refusal to the CLI's rule: exit 1, one ``error:`` line
holding ``message``, no traceback."""

from __future__ import annotations

from click.testing import CliRunner, Result

from plantdreamer.cli import main


def run(*args: object) -> Result:
    return CliRunner().invoke(main, [str(a) for a in args])


def one_error(result: Result, message: str) -> None:
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert result.exit_code == 1 and len(errors) == 1, result.output
    assert "Traceback" not in result.output and "internal error" not in result.output
    assert message in errors[0], result.output
