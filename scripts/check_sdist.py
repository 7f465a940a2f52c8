"""Checks that an sdist holds everything a source build needs and nothing built.

Usage: python scripts/check_sdist.py dist/plantdreamer-X.tar.gz
Every tracked file of the Rust workspace (Cargo.toml, Cargo.lock, crates/) and of the
Python package (pyproject.toml, python/) must be in it, with the licence, the citation and
the documentation's sources and the examples, and no compiled module. Building
from it (`pip install plantdreamer-X.tar.gz`) needs a Rust toolchain: see the README.
"""

from __future__ import annotations

import subprocess
import sys
import tarfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BUILD_INPUTS = ["Cargo.toml", "Cargo.lock", "pyproject.toml", "README.md", "crates", "python"]
# Shipped beside the build inputs: what a user of the sdist may redistribute and cite, the
# documentation (`make docs` builds it, its CLI reference through the hook) and the examples.
SHIPPED = ["LICENSE", "CITATION.cff", "mkdocs.yml", "docs", "scripts/docs_cli_reference.py",
           "examples"]  # fmt: skip


def main(sdist: str) -> None:
    with tarfile.open(sdist) as tar:
        names = tar.getnames()
    top = names[0].split("/")[0]
    inside = {n.removeprefix(f"{top}/") for n in names}
    tracked = subprocess.run(
        ["git", "ls-files", *BUILD_INPUTS, *SHIPPED],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    missing = [n for n in tracked if n not in inside]
    built = [n for n in inside if n.endswith((".so", ".pyd", ".dylib"))]
    missing += [n for n in ("LICENSE", "CITATION.cff") if n not in inside]
    if missing or built or "PKG-INFO" not in inside:
        raise SystemExit(f"bad sdist {sdist}: missing {missing[:10]}, compiled files {built}")
    print(f"sdist {Path(sdist).name}: {len(inside)} files, every build input present")


if __name__ == "__main__":
    main(sys.argv[1])
