"""Prints, one per line, the requirements that build the native module as the Makefile does:
pyproject.toml's [build-system] requires (maturin) and the dev extra's ziglang (the linker
for glibc 2.17). The Makefile installs them into .venv before its first build, so that pip
builds the editable install with .venv's own maturin and zig (no build isolation), the way
`make wheel` builds the wheel, and cargo compiles the core once for both.

Usage: python scripts/build_tools.py > requirements.txt
       python scripts/build_tools.py --extra docs   # an extra's own requirements (`make docs`:
                                                    # installed without rebuilding the core)
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


def build_tools(pyproject: dict) -> list[str]:
    dev = pyproject["project"]["optional-dependencies"]["dev"]
    zig = [r for r in dev if re.split(r"[\s<>=!~;\[]", r, maxsplit=1)[0] == "ziglang"]
    if not zig:
        sys.exit("error: the dev extra in pyproject.toml names no ziglang")
    return [*pyproject["build-system"]["requires"], *zig]


if __name__ == "__main__":
    with (ROOT / "pyproject.toml").open("rb") as f:
        pyproject = tomllib.load(f)
    if sys.argv[1:2] == ["--extra"]:
        print("\n".join(pyproject["project"]["optional-dependencies"][sys.argv[2]]))
    else:
        print("\n".join(build_tools(pyproject)))
