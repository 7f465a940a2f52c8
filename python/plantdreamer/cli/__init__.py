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

# Where a user finds the documentation and reports a bug. The project's home address is
# not known to the package: the docs are in the source tree and the sdist (docs/), and
# tests/test_urls.py fails on an address outside its reviewed list.
DOCS_WHERE = "docs/ in the plantdreamer source and its sdist; COMMAND --help for each command"
REPORT_WHERE = "the repository you got plantdreamer from"

# name -> "module:attribute", in the order of the work (`--help` lists them so): check the
# install, look at plants and scans, train a LoRA, make plants, look at them and render
# them again, make datasets and their label files, then evaluate and ablate.
COMMANDS: dict[str, str] = {
    "info": "plantdreamer.cli.info:info",
    "lsystem": "plantdreamer.cli.lsystem:lsystem",
    "prepare": "plantdreamer.cli.prepare:prepare",
    "lora": "plantdreamer.cli.lora:lora",
    "generate": "plantdreamer.cli.generate:generate",
    "view": "plantdreamer.cli.view:view",
    "render": "plantdreamer.cli.render:render",
    "dataset": "plantdreamer.cli.dataset:dataset",
    "labels": "plantdreamer.cli.labels:labels",
    "gallery": "plantdreamer.cli.gallery:gallery",
    "eval": "plantdreamer.cli.eval:eval_command",
    "ablate": "plantdreamer.cli.ablate:ablate",
}


class _LazyGroup(click.Group):
    """Loads subcommands on demand and turns expected failures into one clear line."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return list(COMMANDS)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """Each command with the whole first sentence of its help, wrapped (click's own
        listing cuts it to the terminal's width, mid-sentence)."""
        rows = []
        for name in self.list_commands(ctx):
            command = self.get_command(ctx, name)
            if command is not None and not command.hidden:
                rows.append((name, command.get_short_help_str(limit=1 << 20)))
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)

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
                    f"internal error ({type(exc).__name__}: {exc}); please report it to "
                    f"{REPORT_WHERE}, with the traceback that PLANTDREAMER_TRACEBACK=1 "
                    f"shows (documentation: {DOCS_WHERE})",
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
    epilog=f"Documentation: {DOCS_WHERE}.",
)
@click.version_option(__version__, "-V", "--version", prog_name="plantdreamer")
def main() -> None:
    """Turn plants into realistic 3D Gaussian Splatting models."""


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
