"""The headline figures: BENCHMARKS.md, the README and the docs' home page show what
benches/headline.json holds (scripts/headline.py renders them), and the citation names
this version."""

import copy
import importlib.util
import re
from pathlib import Path

import plantdreamer

ROOT = Path(__file__).resolve().parent.parent


def _headline():
    spec = importlib.util.spec_from_file_location("headline", ROOT / "scripts" / "headline.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_committed_headlines_match_the_json():
    assert _headline().main(["--check"]) == 0, "run python scripts/headline.py"


def test_a_changed_figure_changes_every_headline():
    headline = _headline()
    fig = headline.load()
    changed = copy.deepcopy(fig)
    best = max(changed["throughput"]["rows"], key=lambda r: r["plants_per_hour"])
    best["plants_per_hour"] = 77.7
    block = re.compile(re.escape(headline.BEGIN) + "(.*?)" + re.escape(headline.END), re.S)
    before, after = headline.rendered(fig), headline.rendered(changed)
    for path in before:
        old, new = (block.search(text).group(1) for text in (before[path], after[path]))
        assert "77.7" in new and "77.7" not in old, path.name
    # Derived, not stored: GPU-hours for 1,000 plants at the new best rate.
    assert f"{1000 / 77.7:.1f}" in after[ROOT / "README.md"]


def test_citation_names_this_version_and_the_paper():
    text = (ROOT / "CITATION.cff").read_text(encoding="utf-8")
    assert re.search(r"^version: (\S+)$", text, re.M).group(1) == plantdreamer.__version__
    assert "PlantDreamer: Achieving Realistic 3D Plant Models" in text
    assert "Apache License" in (ROOT / "LICENSE").read_text(encoding="utf-8")
