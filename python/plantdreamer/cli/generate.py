"""``plantdreamer generate``: a species or a point cloud in, a 3DGS plant out.

The run's options are the settings of ``GenerateConfig``, each under its one name (defaults,
choices and help come from the sections' dataclasses); this module only adds the output folder, ``--resume``, ``--overwrite``,
``--quiet``, ``--view``, ``--seeds`` and ``--print-config`` (not settings of the run). ``--preset`` picks the base values
(``pipeline/settings/presets.py``); only the options given on the command line override them.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import click

from plantdreamer.cli.help_sections import SECTION_TITLES, SectionedCommand, setting_sections
from plantdreamer.cli.options import (
    config_options,
    given_on_command_line,
    options_to_settings,
    typed_options,
)
from plantdreamer.pipeline.settings.config import GenerateConfig
from plantdreamer.viewer import DEFAULT_PORT, HOST

# Options of the command that are no settings of the run: listed under the run's heading.
RUN_OPTIONS = (
    "out_dir",
    "resume_dir",
    "overwrite",
    "seeds",
    "quiet",
    "view",
    "port",
    "print_config",
    "help",
)
# What the end-of-run line lists, when the run wrote it.
FINISHED_FILES = ("renders", "labels", "turntable.gif", "turntable.mp4", "coco.json",
                  "progress.png", "loss.png", "tensorboard", "run.json")  # fmt: skip
# \b keeps click from rewrapping the lines that follow it.
EXAMPLES = """Examples:

\b
  # a bean by the paper's method (the weights: `plantdreamer info --check`)
  plantdreamer generate --species bean --lora lora/bean --out bean
  # a real scan, named in the prompts
  plantdreamer generate --pointcloud scan.ply --species kale --out kale
  # four beans trained together, one folder each under beans/
  plantdreamer generate --species bean --seeds 0-3 --out beans
  # seconds on a CPU, no weights: a quick look at the outputs
  plantdreamer generate --species bean --guidance none --points 2000 \\
      --steps 2 --eval-views 2 --resolution 64 --turntable none --out quick
  # continue a run stopped by Ctrl-C
  plantdreamer generate --resume bean

\b
Every setting above also goes into a dataset spec and `dataset --set NAME=VALUE`.
"""


def build_command() -> click.Command:
    """The command, with options read from ``GenerateConfig`` as it is now."""

    run = SECTION_TITLES[""]
    sections = {**setting_sections(GenerateConfig), **dict.fromkeys(RUN_OPTIONS, run)}

    @click.command(name="generate", cls=SectionedCommand, sections=sections, epilog=EXAMPLES)
    @config_options(GenerateConfig)
    @click.option(
        "--out",
        "out_dir",
        type=click.Path(file_okay=False),
        default="out",
        show_default=True,
        help="The run's folder (with --seeds, one folder per plant in it).",
    )
    @click.option(
        "--resume",
        "resume_dir",
        type=click.Path(file_okay=False),
        help="Continue the run in this folder.",
    )
    @click.option(
        "--overwrite", is_flag=True, help="Replace the outputs of an earlier run in --out."
    )
    @click.option(
        "--seeds",
        help="Several plants trained together, one folder per seed under --out "
        "(<species>-s<seed>): 0-7, 0,3,5 or both.",
    )
    @click.option("--quiet", is_flag=True, help="No progress output.")
    @click.option(
        "--view", is_flag=True, help="Open the result in `plantdreamer view` when the run ends."
    )
    @click.option(
        "--port",
        default=DEFAULT_PORT,
        show_default=True,
        help=f"Port on {HOST} of --view's viewer (checked free before the run starts).",
    )
    @click.option(
        "--print-config",
        is_flag=True,
        help="Print the resolved settings (preset, options, LoRA record; prompts, timestep "
        "phases, cull steps) as JSON and exit without running.",
    )
    @click.pass_context
    def generate(
        ctx: click.Context,
        resume_dir: str | None,
        out_dir: str,
        overwrite: bool,
        seeds: str | None,
        quiet: bool,
        view: bool,
        port: int,
        print_config: bool,
        **options,
    ) -> None:
        """Generate a 3DGS plant; writes plant.ply, renders/, turntable.gif, run.json, log.csv,
        and ground truth per view: labels/, instances/, depth/, transforms.json. At each
        checkpoint (or every --progress-every steps) progress.png (the Gaussians so far) and
        loss.png show how it goes; --tensorboard writes TensorBoard events too."""
        from plantdreamer.errors import RunInterrupted

        started = time.perf_counter()
        given = typed_options(ctx)
        if view and not print_config:  # what --view needs, found before the run, not after
            from plantdreamer.viewer.server import check_port_free, import_viser

            import_viser()
            check_port_free(port)
        try:
            if resume_dir is not None:
                if print_config:
                    raise click.UsageError("--print-config shows a new run; drop --resume")
                if overwrite:
                    raise click.UsageError("--overwrite starts afresh; it cannot go with --resume")
                if "out_dir" in given and Path(out_dir) != Path(resume_dir):
                    raise click.UsageError(
                        "--resume continues the run in its own folder; drop --out"
                    )
                # Settings typed again on resume: checked against the checkpoint, never ignored.
                changes = options_to_settings(GenerateConfig, given_on_command_line(options))
                if seeds is not None:
                    raise click.UsageError("--resume continues a run as it started; drop --seeds")
                results = _run(None, Path(resume_dir), quiet, resume=True, changes=changes)
            else:
                cfgs = _configs(options, seeds)
                if print_config:
                    from plantdreamer.pipeline.settings.resolved import resolved_settings

                    click.echo(json.dumps(resolved_settings(cfgs), indent=2))
                    return
                results = _run(cfgs, Path(out_dir), quiet, group=seeds is not None,
                               overwrite=overwrite)  # fmt: skip
        except RunInterrupted as stop:
            click.secho(
                f"interrupted at step {stop.step}; checkpoint written. "
                f"Continue with: plantdreamer generate --resume {stop.out_dir}",
                err=True,
                fg="yellow",
            )
            raise SystemExit(130) from None
        for line in finished_lines(results, time.perf_counter() - started, view):
            click.echo(line)
        if view:
            from plantdreamer.viewer.server import view_files

            view_files([str(r.ply_path) for r in results], port=port, echo=click.echo)

    return generate


def finished_lines(results: list, seconds: float, viewing: bool) -> list[str]:
    """The end of a run: what each plant wrote, the time it took and the next command."""
    lines = []
    for r in results:
        folder = Path(r.folder)
        made = [name for name in FINISHED_FILES if (folder / name).exists()]
        lines.append(f"wrote {r.ply_path} ({r.gaussians:,} Gaussians) and {', '.join(made)} "
                     f"in {folder}")  # fmt: skip
    from plantdreamer.pipeline.progress import duration_text

    lines.append(f"done in {duration_text(seconds)}")
    if results and not viewing:
        plys = " ".join(str(r.ply_path) for r in results[:4]) + (" ..." if len(results) > 4 else "")
        lines.append(f"next: plantdreamer view {plys}")
    return lines


def _configs(options: dict[str, Any], seeds: str | None) -> list[GenerateConfig]:
    """The run's config, or with ``--seeds`` one per seed (the same settings otherwise),
    each checked before torch is imported (``pipeline.settings.requested``, as the API's)."""
    from plantdreamer.pipeline.settings.requested import requested_configs

    preset = options.pop("preset")
    typed = options_to_settings(GenerateConfig, given_on_command_line(options))
    defaults = options_to_settings(GenerateConfig, options)
    return requested_configs(preset, typed, seeds, base=defaults)


def _run(
    cfgs: list[GenerateConfig] | None,
    out: Path,
    quiet: bool,
    *,
    group: bool = False,
    resume: bool = False,
    changes: dict[str, Any] | None = None,
    overwrite: bool = False,
) -> list:
    """Trains the plants (one in ``out``, or a group with a folder each under it), or
    resumes ``out``; each plant's result. A failed plant of a group makes the command fail
    once the others are written (they are listed first)."""
    from plantdreamer.errors import PlantsFailed
    from plantdreamer.pipeline import FolderPerPlant, PlantAlone, generate_plants
    from plantdreamer.pipeline.runs.layout import found_layout
    from plantdreamer.pipeline.runs.record import GROUP_FILE
    from plantdreamer.pipeline.runs.results import finished_or_raise

    layout = found_layout(out) if resume else FolderPerPlant() if group else PlantAlone()
    grouped = isinstance(layout, FolderPerPlant)
    try:
        results = generate_plants(
            cfgs, out, layout=layout, failures="record" if grouped else "raise",
            resume=resume, changes=changes, overwrite=overwrite, show_progress=not quiet,
        )  # fmt: skip
        return finished_or_raise(results, out / GROUP_FILE)
    except PlantsFailed as failed:
        for result in failed.done:
            click.echo(f"wrote {result.ply_path} ({result.gaussians} Gaussians)")
        raise


generate = build_command()
