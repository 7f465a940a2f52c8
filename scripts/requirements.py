"""Prints, one per line, requirements read from pyproject.toml for the Makefile:

- (no option) the tools that build the native module: [build-system] requires (maturin) and
  the dev extra's ziglang (the linker for glibc 2.17). The Makefile installs them into .venv
  first, so that pip builds the editable install with .venv's own maturin and zig (no build
  isolation), the way `make wheel` builds the wheel, and cargo compiles the core once for
  both;
- ``--dependencies EXTRA...``: the package's dependencies and these extras', the extras it
  names of itself (``plantdreamer[cluster]``) expanded. The Makefile installs them while
  cargo compiles the core (pip would otherwise unpack them only after the build), then
  installs the package itself with ``--no-deps``; and an extra's later (`make docs`,
  `make bench`) without building the core again.

Usage: python scripts/requirements.py > build-tools.txt
       python scripts/requirements.py --dependencies dev viewer
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: pip carries tomli
    from pip._vendor import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]


def requirement_name(requirement: str) -> str:
    """The distribution name a requirement string starts with."""
    return re.split(r"[\s<>=!~;\[]", requirement, maxsplit=1)[0]


def build_tools(pyproject: dict) -> list[str]:
    dev = pyproject["project"]["optional-dependencies"]["dev"]
    zig = [r for r in dev if requirement_name(r) == "ziglang"]
    if not zig:
        sys.exit("error: the dev extra in pyproject.toml names no ziglang")
    return [*pyproject["build-system"]["requires"], *zig]


def dependencies(pyproject: dict, extras: list[str]) -> list[str]:
    """``project.dependencies`` and every named extra's requirements, in order, each once;
    a requirement on the package itself (``name[extra]``) contributes that extra's."""
    name = pyproject["project"]["name"]
    optional = pyproject["project"]["optional-dependencies"]
    out: list[str] = []
    seen_extras: set[str] = set()

    def add(requirements: list[str]) -> None:
        for requirement in requirements:
            if requirement_name(requirement) != name:
                if requirement not in out:
                    out.append(requirement)
                continue
            named = re.search(r"\[([^\]]*)\]", requirement)
            for extra in named.group(1).split(",") if named else []:
                add_extra(extra.strip())

    def add_extra(extra: str) -> None:
        if extra not in optional:
            sys.exit(f"error: pyproject.toml has no extra {extra!r}")
        if extra not in seen_extras:
            seen_extras.add(extra)
            add(optional[extra])

    add(pyproject["project"]["dependencies"])
    for extra in extras:
        add_extra(extra)
    return out


if __name__ == "__main__":
    with (ROOT / "pyproject.toml").open("rb") as f:
        pyproject = tomllib.load(f)
    if sys.argv[1:2] == ["--dependencies"]:
        print("\n".join(dependencies(pyproject, sys.argv[2:])))
    else:
        print("\n".join(build_tools(pyproject)))
