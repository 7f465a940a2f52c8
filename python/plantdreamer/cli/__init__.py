"""The ``plantdreamer`` command.

Subcommands live in their own modules and are imported only when used, so ``--help`` stays
fast (torch is not imported). Each module must keep its top-level imports light.
To add a command: write ``cli/<name>.py`` exposing a click command and list it below.
"""

from __future__ import annotations

import importlib
import os
import sys
import warnings

import click

from plantdreamer import __version__
from plantdreamer.errors import PlantDreamerError

# Where a user of the wheel finds the documentation and reports a bug: pyproject.toml's
# [project.urls] (a test keeps them the same). The sdist also carries docs/.
DOCS_URL = "https://github.com/plantdreamer/plantdreamer/tree/main/docs"
ISSUES_URL = "https://github.com/plantdreamer/plantdreamer/issues"

# name -> "module:attribute". Only commands that work are listed here.
COMMANDS: dict[str, str] = {
    "ablate": "plantdreamer.cli.ablate:ablate",
    "eval": "plantdreamer.cli.eval:eval_command",
    "dataset": "plantdreamer.cli.dataset:dataset",
    "gallery": "plantdreamer.cli.gallery:gallery",
    "generate": "plantdreamer.cli.generate:generate",
    "info": "plantdreamer.cli.info:info",
    "labels": "plantdreamer.cli.labels:labels",
    "lora": "plantdreamer.cli.lora:lora",
    "lsystem": "plantdreamer.cli.lsystem:lsystem",
    "prepare": "plantdreamer.cli.prepare:prepare",
    "render": "plantdreamer.cli.render:render",
    "view": "plantdreamer.cli.view:view",
}


class _LazyGroup(click.Group):
    """Loads subcommands on demand and turns expected failures into one clear line."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(COMMANDS)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        target = COMMANDS.get(cmd_name)
        if target is None:
            return None
        module_name, attr = target.split(":")
        return getattr(importlib.import_module(module_name), attr)

    def invoke(self, ctx: click.Context) -> object:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            try:
                return super().invoke(ctx)
            except (PlantDreamerError, OSError) as exc:
                # Expected failures (bad input, missing files or models): one line, exit 1.
                _fail(ctx, str(exc))
            except MemoryError as exc:
                detail = str(exc).removeprefix("out of memory: ")  # the native core's own
                _fail(ctx, f"out of memory{f' ({detail})' if detail else ''}; use smaller sizes")
            except KeyboardInterrupt:
                click.secho("interrupted", err=True, fg="yellow")
                ctx.exit(130)
            except (click.ClickException, click.exceptions.Exit, click.exceptions.Abort):
                raise
            except Exception as exc:
                # A bug: still one line for the user, the traceback on request.
                if os.environ.get("PLANTDREAMER_TRACEBACK"):
                    raise
                _fail(
                    ctx,
                    f"internal error ({type(exc).__name__}: {exc}); please report it at "
                    f"{ISSUES_URL} with the traceback that PLANTDREAMER_TRACEBACK=1 shows "
                    f"(documentation: {DOCS_URL})",
                )
        return None


def _fail(ctx: click.Context, message: str) -> None:
    click.secho(f"error: {' '.join(message.split())}", err=True, fg="red")
    ctx.exit(1)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    click.secho(f"warning: {' '.join(str(message).split())}", err=True, fg="yellow")


@click.group(
    cls=_LazyGroup,
    context_settings={"help_option_names": ["-h", "--help"]},
    epilog=f"Documentation: {DOCS_URL}",
)
@click.version_option(__version__, "-V", "--version", prog_name="plantdreamer")
def main() -> None:
    """Turn plants into realistic 3D Gaussian Splatting models."""


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
