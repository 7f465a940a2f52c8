"""scripts/requirements.py: the lists the Makefile installs from pyproject.toml."""

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _script():
    path = ROOT / "scripts" / "requirements.py"
    spec = importlib.util.spec_from_file_location("requirements_script", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _pyproject() -> dict:
    with (ROOT / "pyproject.toml").open("rb") as f:
        return _script().tomllib.load(f)  # tomllib, or pip's tomli before Python 3.11


def test_dependencies_expand_the_extras_the_package_names_of_itself():
    script, pyproject = _script(), _pyproject()
    optional = pyproject["project"]["optional-dependencies"]
    listed = script.dependencies(pyproject, ["dev", "viewer"])
    # dev names plantdreamer[cluster], [docs], [open3d] and [tensorboard]: their requirements
    # come in its place, and nothing names the package itself (pip would try to install it).
    expected = [
        *pyproject["project"]["dependencies"],
        *optional["cluster"],
        *optional["docs"],
        *optional["open3d"],
        *optional["tensorboard"],
        *optional["viewer"],
        *(r for r in optional["dev"] if not r.startswith("plantdreamer")),
    ]
    assert sorted(listed) == sorted(set(expected))
    assert len(listed) == len(set(listed))
    assert not [r for r in listed if script.requirement_name(r) == "plantdreamer"]
    base = pyproject["project"]["dependencies"]
    assert listed[: len(base)] == base


def test_an_extra_named_twice_or_through_another_comes_once():
    script = _script()
    pyproject = {
        "project": {
            "name": "pkg",
            "dependencies": ["a>=1"],
            "optional-dependencies": {
                "x": ["pkg[y]", "b", "pkg[y,z]"],
                "y": ["c", "a>=1"],
                "z": ["pkg[x]", "d"],
            },
        }
    }
    assert script.dependencies(pyproject, ["x", "z", "x"]) == ["a>=1", "c", "b", "d"]


def test_an_unknown_extra_is_an_error():
    with pytest.raises(SystemExit, match="no extra 'nope'"):
        _script().dependencies(_pyproject(), ["nope"])


def test_build_tools_are_the_build_system_and_ziglang():
    script, pyproject = _script(), _pyproject()
    tools = script.build_tools(pyproject)
    backend = pyproject["build-system"]["requires"]
    assert tools[: len(backend)] == backend
    assert [script.requirement_name(r) for r in tools].count("ziglang") == 1
