"""The plantdreamer command: help, version, and one-line errors."""

import dataclasses
import re
import subprocess
import sys

import click
from click.testing import CliRunner

import plantdreamer
from plantdreamer import cli
from plantdreamer.cli import COMMANDS, main


def test_help_lists_every_command_in_the_order_of_the_work_with_whole_summaries():
    result = CliRunner().invoke(main, ["--help"], terminal_width=80)
    assert result.exit_code == 0
    listing = result.output.split("Commands:")[1]
    # The work's order: install check, plants, scans, LoRA, generate, look, datasets, scores.
    order = ["info", "lsystem", "prepare", "lora", "generate", "view", "render", "dataset",
             "labels", "gallery", "eval", "ablate"]  # fmt: skip
    assert sorted(order) == sorted(COMMANDS)
    starts = [re.search(rf"^  {name} ", listing, re.M) for name in order]
    assert all(starts), listing
    assert [m.start() for m in starts if m] == sorted(m.start() for m in starts if m)
    # Each summary whole: click cuts them to the terminal's width, with "...".
    assert "..." not in listing
    generate = main.get_command(click.Context(main), "generate")
    assert generate is not None
    summary = " ".join(generate.get_short_help_str(limit=1 << 20).split())
    assert summary.endswith(".") and summary in " ".join(listing.split())


@click.command()
def _boom() -> None:
    raise RuntimeError("a bug")


def test_help_and_internal_errors_say_where_the_documentation_is_without_an_address(
    monkeypatch,
):
    # The project's home address is not known: no URL, the docs' place in the source.
    help_text = CliRunner().invoke(main, ["--help"]).output
    assert cli.DOCS_WHERE.split(";")[0] in " ".join(help_text.split())
    assert "http" not in help_text

    monkeypatch.setitem(COMMANDS, "boom", f"{__name__}:_boom")
    monkeypatch.delenv("PLANTDREAMER_TRACEBACK", raising=False)
    result = CliRunner().invoke(main, ["boom"])
    assert result.exit_code == 1 and "internal error" in result.output
    assert "PLANTDREAMER_TRACEBACK=1" in result.output and "http" not in result.output


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


# --- one concept, one name in every command ---------------------------------------------------

# Each concept the commands share, under its one option name, with the other spellings it has
# had (kept hidden, for old command lines) or could be given: no command shows one of them.
CONCEPTS = {
    "--out": ("--output", "--out-dir", "--output-dir", "--dest"),
    "--seeds": ("--count", "--seed-start", "--num-plants", "--plants"),
    "--seed": ("--random-seed", "--rng-seed"),
    "--species": ("--plant", "--species-list"),
    "--pointcloud": ("--pointclouds", "--point-cloud", "--cloud"),
    "--points": ("--target", "--n-points", "--num-points"),
    "--scene-size": ("--size", "--normalize-size"),
    "--eval-views": ("--views", "--n-views"),
    "--eval-distance": ("--distance",),
    "--eval-elevation-deg": ("--elevation",),
    "--eval-fovy-deg": ("--fovy", "--fov"),
    "--resolution": ("--image-size", "--res"),
    "--background": ("--bg", "--background-color"),
    "--prompt-template": ("--caption-template", "--template"),
    "--color-init": ("--colors", "--colour-init"),
    "--lr": ("--learning-rate",),
    "--overwrite": ("--force",),
}
OTHER_SPELLING = {old: new for new, olds in CONCEPTS.items() for old in olds}
# Commands whose options of a generate setting's name are their own settings, not generate's
# with generate's default: `dataset` applies given ones over a spec (unset: generate's), and
# `lora train` is another run (LoraTrainConfig: its steps, resolution, seed).
OWN_DEFAULTS = {"dataset", "lora train"}
# Options of a generate setting's name whose default is their command's own, and why.
OWN_DEFAULT = {
    ("render", "--labels"): "a PLY of another tool has no labels: ground truth when asked",
    ("view", "--labels"): "the viewer opens coloured as rendered unless asked",
}


def every_command():
    """(path, command) of every command, the groups' subcommands too, walked from `main`."""
    import click

    ctx = click.Context(main)

    def walk(group, path):
        for name in group.list_commands(ctx):
            command = group.get_command(ctx, name)
            yield f"{path} {name}".strip(), command
            if isinstance(command, click.Group):
                yield from walk(command, f"{path} {name}")

    return list(walk(main, ""))


def ctx(command):
    import click

    return click.Context(command)


def shown_options(command):
    import click

    return [p for p in command.params if isinstance(p, click.Option) and not p.hidden]


def test_every_command_spells_each_concept_one_way_with_generates_default():
    from plantdreamer import settings
    from plantdreamer.pipeline.settings.config import GenerateConfig

    generate = {f"--{s.name}": s.default for s in settings.walk(GenerateConfig)}
    problems = []
    for path, command in every_command():
        shown = CliRunner().invoke(main, [*path.split(), "--help"])
        assert shown.exit_code == 0, (path, shown.output)
        for option in shown_options(command):
            for name in option.opts + option.secondary_opts:
                if not name.startswith("--") or name == "--help":
                    continue
                if name not in shown.output:
                    problems.append(f"{path} {name}: not in its --help")
                if name in OTHER_SPELLING:
                    problems.append(f"{path} {name}: spelled {OTHER_SPELLING[name]} elsewhere")
                own = path in OWN_DEFAULTS or (path, name) in OWN_DEFAULT or option.multiple
                default = None if option.required else option.get_default(ctx(command))
                if name in generate and not own and default != generate[name]:
                    problems.append(f"{path} {name}: default {default!r}, "
                                    f"generate's {generate[name]!r}")  # fmt: skip
            if not (option.help or "").strip():
                problems.append(f"{path} {option.opts[0]}: no help text")
    assert not problems, "\n".join(problems)


def test_the_concept_table_names_options_that_exist():
    """The table's names are the commands' names (a renamed option must update the table)."""
    shown = {n for _, c in every_command() for o in shown_options(c) for n in o.opts}
    assert set(CONCEPTS) <= shown, set(CONCEPTS) - shown


def test_generate_help_lists_its_options_by_section_then_examples():
    from plantdreamer.cli.help_sections import SECTION_TITLES
    from plantdreamer.pipeline.settings.config import GenerateConfig

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
    assert rows[f"LoRA {lora}"].startswith(f"damaged: LoRA file '{lora / LORA_WEIGHT_NAME}'")
    assert "extra [cluster]" in rows and "extra [dev]" not in rows
    assert result.exit_code == 1  # a model is missing
    result = CliRunner().invoke(main, ["info", "--check", "--lora", str(tmp_path / "nothere")])
    assert f"LoRA {tmp_path / 'nothere'}" in result.output and "missing: LoRA" in result.output
    assert result.exit_code == 1


def test_dataset_help_ends_with_examples_that_parse(tmp_path):
    import shlex

    from plantdreamer.cli.dataset import dataset

    help_text = CliRunner().invoke(main, ["dataset", "--help"]).output
    assert "Examples:" in help_text and "--dry-run" in help_text.split("Examples:")[1]
    spec = tmp_path / "spec.toml"
    spec.write_text('[[group]]\nspecies = "bean"\n')
    examples = [
        line.strip() for line in help_text.split("Examples:")[1].splitlines()
        if line.strip().startswith("plantdreamer dataset")
    ]  # fmt: skip
    assert len(examples) >= 4
    for example in examples:
        args = [str(spec) if a == "spec.toml" else a for a in shlex.split(example)[2:]]
        # Parsed as the command would parse them (no run): every option exists and is valid.
        with dataset.make_context("dataset", args) as ctx:
            assert ctx.params["out_dir"]
