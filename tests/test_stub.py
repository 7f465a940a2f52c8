"""_core.pyi must describe the compiled module exactly (mypy.stubtest compares them)."""

import subprocess
import sys
from pathlib import Path

import pytest


def test_stub_matches_compiled_module():
    pytest.importorskip("mypy")
    stub_dir = Path(__file__).resolve().parents[1] / "python"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "mypy.stubtest",
            "plantdreamer._core",
            "--mypy-config-file",
            str(stub_dir.parent / "pyproject.toml"),
        ],
        capture_output=True,
        text=True,
        cwd=stub_dir,
    )
    assert result.returncode == 0, result.stdout + result.stderr
