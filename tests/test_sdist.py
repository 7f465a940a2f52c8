"""The sdist as `make wheel` builds it (maturin sdist: no compiling, about a second): every
build input, the documentation with its hook, the examples, and only reviewed addresses."""

from __future__ import annotations

import runpy
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest

from test_urls import unknown_urls

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def sdist(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sdist")
    maturin = Path(sys.executable).parent / "maturin"
    made = subprocess.run(
        [str(maturin), "sdist", "--out", str(out)], cwd=ROOT, capture_output=True, text=True,
        timeout=300,
    )  # fmt: skip
    assert made.returncode == 0, made.stderr[-2000:]
    (path,) = out.glob("plantdreamer-*.tar.gz")
    return path


def test_the_sdist_holds_the_examples_and_the_docs_with_their_hook(sdist):
    with tarfile.open(sdist) as tar:
        names = {n.split("/", 1)[1] for n in tar.getnames() if "/" in n}
    for name in ("examples/generate_plant.py", "examples/quickstart.ipynb", "mkdocs.yml",
                 "docs/index.md", "scripts/docs_cli_reference.py"):  # fmt: skip
        assert name in names, name
    # Every tracked file of examples/ is shipped.
    listed = subprocess.run(["git", "ls-files", "examples"], cwd=ROOT, capture_output=True,
                            text=True, check=True)  # fmt: skip
    examples = set(listed.stdout.split())
    assert examples and examples <= names
    # The check `make test-wheel` runs passes on it.
    check = runpy.run_path(str(ROOT / "scripts" / "check_sdist.py"))
    check["main"](str(sdist))


def test_every_address_in_the_sdist_is_a_known_one(sdist):
    with tarfile.open(sdist) as tar:
        files = {m.name: tar.extractfile(m).read() for m in tar.getmembers() if m.isfile()}  # type: ignore[union-attr]
    assert len(files) > 100
    found = unknown_urls(files)
    assert not found, "unknown addresses:\n" + "\n".join(found)
