"""Every address the project gives is one known to exist: the tree, the wheel's metadata and
(when `make test-wheel` names it) the built wheel and sdist.

The project's own home address is not known, so the files say "this repository" and link
relatively; an address outside the reviewed list below fails here, with where it is.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

# Reviewed: each is the published page of the thing it names.
KNOWN_URLS = {
    "https://arxiv.org/abs/2505.15528": "the PlantDreamer paper",
    "https://github.com/Lewis-Stuart-11/PlantDreamer": "the authors' code",
    "https://plantimages.nottingham.ac.uk/datasets.html#plantdreamer": "the authors' data",
    "https://download.pytorch.org/whl/cpu": "PyTorch's CPU-only wheels",
    "https://huggingface.co": "the Hugging Face hub (HF_ENDPOINT's default)",
    "https://huggingface.co/stabilityai/stable-diffusion-2-1-base/blob/main/LICENSE.md": (
        "Stable Diffusion 2.1's licence"
    ),
    "https://github.com/pierotofy/OpenSplat": "OpenSplat, the benchmarks' CPU peer",
    "http://www.apache.org/licenses/": "the Apache License (LICENSE's own text)",
    "http://www.apache.org/licenses/LICENSE-2.0": "the Apache License (LICENSE's own text)",
    "https://github.com/rust-lang/crates.io-index": "crates.io's index (Cargo.lock)",
}
# Hosts of this machine or unroutable, names reserved for examples (RFC 2606: *.example),
# and addresses built at run time ("{host}"): what the viewer serves and the tests probe.
LOCAL_HOSTS = {"127.0.0.1", "localhost", "10.255.255.1"}

URL = re.compile(r"https?://(?:\{[^}\s]*\}|[^\s<>\"'`(){}\[\]|\\])+")


def urls_in(text: str) -> set[str]:
    """The addresses in ``text``, without the punctuation that ends a sentence after one."""
    found = {m.group(0).rstrip(".,;:!?*") for m in URL.finditer(text)}
    return {u for u in found if not u.endswith("://")}  # a scheme named in prose


def unknown(url: str) -> bool:
    """Whether ``url`` is outside the reviewed list and no local address."""
    if url in KNOWN_URLS:
        return False
    host = re.split(r"[/:?#]", url.split("://", 1)[1], maxsplit=1)[0]
    # "registry+https://..." and cargo's "?branch" forms name the index above.
    local = host in LOCAL_HOSTS or host.endswith(".example") or host.startswith("{")
    return not (local or url.rstrip("/") in KNOWN_URLS)


def project_files() -> list[Path]:
    """The tree's files: tracked and new ones (ignored build outputs left out)."""
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT, capture_output=True, check=True,
    ).stdout.decode()  # fmt: skip
    return [ROOT / name for name in sorted(set(listed.split("\0"))) if name]


def text_of(data: bytes) -> str | None:
    """A file's text, or None for binary data (images, the compiled module)."""
    if b"\0" in data[:8192]:
        return None
    return data.decode("utf-8", errors="replace")


def own_sbom_text(data: bytes) -> str:
    """Of a wheel's software bill of materials (CycloneDX, which maturin writes), the
    entries of this project's own crates (built from a path, not a registry): the other
    crates' addresses are their own manifests', as crates.io serves them."""
    bom = json.loads(data)
    own = [bom.get("metadata", {}).get("component", {})]
    own += [c for c in bom.get("components", []) if "download_url=file:" in str(c.get("purl", ""))]
    return json.dumps(own)


def unknown_urls(files: dict[str, bytes]) -> list[str]:
    """``where: url`` for each unknown address in ``files`` (name -> contents)."""
    found = []
    for name, data in sorted(files.items()):
        text = own_sbom_text(data) if name.endswith(".cyclonedx.json") else text_of(data)
        if text is not None:
            found += [f"{name}: {u}" for u in sorted(urls_in(text)) if unknown(u)]
    return found


def test_the_url_pattern_finds_addresses_as_written():
    text = (
        "see https://arxiv.org/abs/2505.15528. Or (https://x.example/a_b), `http://h:{port}/p`,"
        "\n<https://y.example/q?a=1&b=2>, [t](https://z.example/#f) and http://{H}:{s.port()}"
    )
    assert urls_in(text) == {
        "https://arxiv.org/abs/2505.15528", "https://x.example/a_b", "http://h:{port}/p",
        "https://y.example/q?a=1&b=2", "https://z.example/#f", "http://{H}:{s.port()}",
    }  # fmt: skip
    assert not unknown("https://arxiv.org/abs/2505.15528")
    assert not unknown("http://127.0.0.1:{port}/json/list") and not unknown("http://{HOST}:8")
    # The address the project once gave itself, and a near miss of a known one.
    assert unknown("https://github.com/" + "plantdreamer/plantdreamer")
    assert unknown("https://arxiv.org/abs/" + "2505.15529")
    assert unknown("http://h:{port}/p")


def test_every_address_in_the_tree_is_a_known_one():
    files = {}
    for path in project_files():
        # This file holds the reviewed list and the pattern's own examples.
        if path.is_file() and not path.is_symlink() and path != Path(__file__).resolve():
            files[str(path.relative_to(ROOT))] = path.read_bytes()
    assert len(files) > 100 and "README.md" in files
    found = unknown_urls(files)
    assert not found, "unknown addresses:\n" + "\n".join(found)


def test_every_address_in_the_wheels_metadata_is_a_known_one(tmp_path):
    # The metadata maturin writes into the wheel (Project-URL, the README as description),
    # made from pyproject.toml and Cargo.toml as the build makes it, without compiling.
    code = "import maturin, sys; print(maturin.prepare_metadata_for_build_wheel(sys.argv[1]))"
    made = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path)], cwd=ROOT, capture_output=True, text=True,
        timeout=120,
    )  # fmt: skip
    assert made.returncode == 0, made.stderr[-2000:]
    metadata = tmp_path / made.stdout.split()[-1] / "METADATA"
    text = metadata.read_text(encoding="utf-8")
    assert "Project-URL: Paper, https://arxiv.org/abs/2505.15528" in text
    found = unknown_urls({"METADATA": text.encode()})
    assert not found, "unknown addresses:\n" + "\n".join(found)


def _archive_files(path: Path) -> dict[str, bytes]:
    if path.suffix == ".whl":
        with zipfile.ZipFile(path) as z:
            return {n: z.read(n) for n in z.namelist() if not n.endswith("/")}
    with tarfile.open(path) as t:
        return {
            m.name: t.extractfile(m).read()  # type: ignore[union-attr]
            for m in t.getmembers()
            if m.isfile()
        }


@pytest.mark.skipif(
    not os.environ.get("PLANTDREAMER_BUILT"),
    reason="needs a built wheel and sdist: `make test-wheel` sets PLANTDREAMER_BUILT",
)
def test_every_address_in_the_built_wheel_and_sdist_is_a_known_one():
    built = [Path(p) for p in os.environ["PLANTDREAMER_BUILT"].split()]
    assert built and all(p.is_file() for p in built), built
    for archive in built:
        files = _archive_files(archive)
        assert files, archive
        if archive.suffix == ".whl":  # the metadata and the package's own files are read
            assert any(n.endswith(".dist-info/METADATA") for n in files), archive
        found = unknown_urls(files)
        assert not found, f"unknown addresses in {archive}:\n" + "\n".join(found)
