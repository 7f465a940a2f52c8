"""The README's first screen: what it is and costs, the two commands with what each shows
and costs, and a first plant; CI runs the README's test command and the commands exist."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FIRST_SCREEN_LINES = 90  # the README up to its first real plant, at most


def readme_blocks(text: str) -> list[str]:
    """The README's fenced bash blocks, in order."""
    return re.findall(r"```bash\n(.*?)```", text, re.S)


def commands(block: str) -> list[str]:
    """A block's commands, without their comments."""
    return [line.split("#")[0].strip() for line in block.splitlines() if line.split("#")[0].strip()]


def test_the_first_screen_gives_the_two_commands_then_a_first_plant():
    text = (ROOT / "README.md").read_text()
    first = "\n".join(text.splitlines()[:FIRST_SCREEN_LINES])
    assert first.index("## What it costs") < first.index("## Start here: two commands")
    blocks = readme_blocks(first)
    assert commands(blocks[0]) == ["make demo", "make test"]
    assert any("--guidance none" in c for c in commands(blocks[1]))
    # What each shows, with its time and disk on the 2-core machine.
    start = first.split("## Start here: two commands")[1]
    for said in ("**`make demo`**", "**`make test`**", "masked PSNR", "2-core machine",
                 "GB of dependencies", "wrote 48 MB"):  # fmt: skip
        assert said in start, said
    assert re.search(r"\d+ min \d+ s", start)


def test_ci_runs_the_readmes_test_command_and_make_has_both():
    readme = (ROOT / "README.md").read_text()
    two = commands(readme_blocks(readme)[0])
    ci = commands((ROOT / ".ci" / "run").read_text())
    assert "make test" in two and "make test" in ci
    # Both are targets of the Makefile that make knows (make -n prints, runs nothing).
    for command in two:
        target = command.split()[1]
        shown = subprocess.run(
            ["make", "-n", "-C", str(ROOT), target], capture_output=True, text=True, timeout=60
        )
        assert shown.returncode == 0 and shown.stdout.strip(), (target, shown.stderr)
