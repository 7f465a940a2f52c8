"""The disk a set-up takes: the installed files of the dependencies `make setup` installs
(pyproject's, with the extras given, and everything they require), as their RECORD files
list them in the virtualenv that runs this script, and the Rust build outputs in target/.

Packages the venv holds beyond those (other extras, a user's own) are left out, so the
figure is that of a fresh set-up whatever else the venv holds.

    .venv/bin/python scripts/install_size.py [EXTRA ...]     # default: dev viewer (make setup)
"""

from __future__ import annotations

import importlib.metadata as metadata
import os
import subprocess
import sys
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parent.parent


def requirements(extras: list[str]) -> list[Requirement]:
    """What scripts/requirements.py lists for ``extras`` (the Makefile's list)."""
    listed = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "requirements.py"), "--dependencies", *extras],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    return [Requirement(line) for line in listed.splitlines() if line.strip()]


def closure(roots: list[Requirement]) -> dict[str, metadata.Distribution]:
    """The installed distributions ``roots`` need, with what they require in turn."""
    installed = {canonicalize_name(d.metadata["Name"]): d for d in metadata.distributions()}
    found: dict[str, metadata.Distribution] = {}
    todo = [(r, "") for r in roots]
    seen: set[tuple[str, str]] = set()
    while todo:
        req, extra = todo.pop()
        if req.marker is not None and not req.marker.evaluate({"extra": extra}):
            continue
        name = canonicalize_name(req.name)
        for wanted in ["", *sorted(req.extras)]:
            if (name, wanted) in seen:
                continue
            seen.add((name, wanted))
            dist = installed.get(name)
            if dist is None:
                raise SystemExit(f"{name} is not installed in {sys.prefix}")
            found[name] = dist
            todo += [(Requirement(r), wanted) for r in dist.requires or []]
    return found


def installed_bytes(dists: dict[str, metadata.Distribution]) -> int:
    total = 0
    for dist in dists.values():
        for file in dist.files or []:
            try:
                total += os.path.getsize(dist.locate_file(file))
            except OSError:
                pass
    return total


def folder_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file() and not p.is_symlink())


def main(extras: list[str]) -> int:
    dists = closure(requirements(extras or ["dev", "viewer"]))
    size = installed_bytes(dists)
    torch = installed_bytes(
        {n: d for n, d in dists.items() if n == "torch" or n.startswith("nvidia")}
    )
    print(f"dependencies ({', '.join(extras or ['dev', 'viewer'])}): {len(dists)} packages, "
          f"{size / 1e9:.2f} GB installed; torch and its CUDA libraries {torch / 1e9:.2f} GB")  # fmt: skip
    target = ROOT / "target"
    if target.is_dir():
        for sub in sorted(p for p in target.iterdir() if p.is_dir()):
            print(f"target/{sub.name}: {folder_bytes(sub) / 1e9:.2f} GB")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
