"""Under a memory limit (``ulimit -v``, as HPC schedulers set) a native call whose buffers
do not fit raises MemoryError, and the command line says so in one line: the core reserves
the buffers the data sizes fallibly (``crates/splat_core/src/memory.rs``) instead of
aborting the process.

The limit is set in a child process once it has imported what it needs: its address
space now plus a margin far below what the call asks for (a 16384 x 16384 render: 3 GiB
of colour alone), so nothing large is ever allocated.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
LIMITED = textwrap.dedent(
    """
    import resource, sys
    import numpy as np
    sys.path.insert(0, {tests!r})
    import raster_native

    def vm_size():
        with open("/proc/self/status") as f:
            line = next(x for x in f if x.startswith("VmSize"))
        return int(line.split()[1]) * 1024

    W = 16384
    means = np.zeros((1, 3), np.float32)
    quats = np.array([[1, 0, 0, 0]], np.float32)
    scales = np.full((1, 3), -2, np.float32)
    opacities = np.ones(1, np.float32)
    colors = np.ones((1, 3), np.float32)
    viewmats = np.eye(4, dtype=np.float32)[None]
    viewmats[0, 2, 3] = 5
    Ks = np.array([[[W, 0, W / 2], [0, W, W / 2], [0, 0, 1]]], np.float32)
    raster_native.forward(means, quats, scales, opacities, colors, viewmats, Ks, 16, 16)
    limit = vm_size() + 256 * 2**20
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    try:
        raster_native.forward(means, quats, scales, opacities, colors, viewmats, Ks, W, W)
    except MemoryError as exc:
        print("MemoryError:", exc)
    """
)


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads /proc (Linux)")
def test_a_render_too_large_for_the_limit_is_a_memory_error_not_an_abort():
    proc = subprocess.run([sys.executable, "-c", LIMITED.format(tests=str(TESTS))],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 0, (proc.returncode, proc.stderr[-2000:])  # -6: aborted
    assert proc.stdout.startswith("MemoryError: out of memory: 3.0 GiB could not be allocated")


@pytest.mark.slow
def test_render_under_ulimit_says_out_of_memory_in_one_line(tmp_path):
    import numpy as np

    from plantdreamer.io import write_splat_ply
    from plantdreamer.pipeline.model.init import init_gaussians

    pts = np.random.default_rng(0).normal(size=(200, 3)).astype(np.float32)
    write_splat_ply(tmp_path / "model.ply", init_gaussians(pts, None, 0.5))
    probe = [sys.executable, "-c", "import torch, plantdreamer.cli, plantdreamer.pipeline.model;"
             "print(next(x for x in open('/proc/self/status') if x.startswith('VmSize'))"
             ".split()[1])"]  # fmt: skip
    kib = int(subprocess.run(probe, capture_output=True, text=True, check=True).stdout)
    limit = kib + 700 * 1024  # what the command needs, and far less than 8192^2 buffers
    command = (f"ulimit -v {limit}; exec {sys.executable} -m plantdreamer render model.ply "
               "--out views --eval-views 1 --resolution 8192 --turntable none")  # fmt: skip
    proc = subprocess.run(["bash", "-c", command], cwd=tmp_path, capture_output=True,
                          text=True, timeout=300)  # fmt: skip
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 1, (proc.returncode, proc.stderr[-2000:])
    assert len(errors) == 1 and errors[0].startswith("error: out of memory"), proc.stderr
    assert "Traceback" not in proc.stderr
