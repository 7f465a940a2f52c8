"""Every writer is atomic: a write cut short by a file-size limit leaves the previous file.

Each case runs in a subprocess under ``RLIMIT_FSIZE``: with SIGXFSZ ignored the write fails
with EFBIG (the writer must raise and remove its temporary file); with the default action
the process is killed mid-write (the previous file must still be intact).
"""

import subprocess
import sys
import textwrap

import pytest

RANDOM_RGB = "rng.integers(0, 255, (300, 300, 3), np.uint8)"

# name -> (file name, code writing a payload far larger than the limit to `path`)
WRITERS = {
    "bytes": ("a.bin", "atomic.write_bytes(path, b'x' * 200_000)"),
    "text": ("a.txt", "atomic.write_text(path, 'x' * 200_000)"),
    "json": ("a.json", "atomic.write_json(path, {'x': list(range(50_000))})"),
    "png": ("a.png", f"atomic.write_image(path, {RANDOM_RGB})"),
    "pil": (
        "a.png",
        f"from PIL import Image\natomic.write_image(path, Image.fromarray({RANDOM_RGB}))",
    ),
    "gif": (
        "t.gif",
        "from plantdreamer.pipeline.outputs import write_turntable\n"
        f"write_turntable(path, [{RANDOM_RGB} for _ in range(8)], 8)",
    ),
    "renders": (
        "view_000.png",
        f"from plantdreamer.pipeline.outputs import write_renders\n"
        f"write_renders(path.parent, [{RANDOM_RGB}])",
    ),
    "log_csv": (
        "log.csv",
        "from plantdreamer.pipeline.outputs import write_log_csv\n"
        "write_log_csv(path, [{'step': i, 'loss': 0.5, 'gaussians': 9} for i in range(20_000)])",
    ),
    "run_json": (
        "run.json",
        "from plantdreamer.pipeline.outputs import write_json\n"
        "write_json(path, {'events': list(range(50_000))})",
    ),
    "ply": (
        "cloud.ply",
        "from plantdreamer.cloud import PointCloud\nfrom plantdreamer.io import write_ply\n"
        "write_ply(path, PointCloud(rng.random((50_000, 3), dtype=np.float32)))",
    ),
    "ply_ascii": (
        "cloud.ply",
        "from plantdreamer.cloud import PointCloud\nfrom plantdreamer.io import write_ply\n"
        "write_ply(path, PointCloud(rng.random((50_000, 3), dtype=np.float32)), binary=False)",
    ),
    "splat_ply": (
        "plant.ply",
        "from plantdreamer.io import write_splat_ply\n"
        "from plantdreamer.pipeline.model.init import init_gaussians\n"
        "write_splat_ply(path, init_gaussians(rng.random((5000, 3), dtype=np.float32), None, 0.5))",
    ),
    "checkpoint": (
        "checkpoint.pt",
        "import torch\nfrom plantdreamer.pipeline.state.checkpoint import save_checkpoint\n"
        "save_checkpoint(path.parent, {'x': torch.zeros(100_000)})",
    ),
    "eval_json": (
        "report.json",
        "from plantdreamer.eval.report import write_json\n"
        "from plantdreamer.eval.evaluate import EvalResult\n"
        "write_json(EvalResult([], (0.5, 0.5, 0.5)), path, padding='x' * 200_000)",
    ),
    "ablation_md": (
        "ablation.md",
        "from plantdreamer.eval.report import write_ablation_table\n"
        "write_ablation_table({f'setting{i}' * 20: float(i) for i in range(2000)}, path.parent)",
    ),
    "mesh": (
        "plant.obj",
        "from click.testing import CliRunner\nfrom plantdreamer.cli import main\n"
        "r = CliRunner().invoke(main, ['lsystem', 'bean', '--mesh', str(path), '--overwrite'])\n"
        "print(r.output)\n"
        "sys.exit(3 if r.exit_code == 1 and 'error:' in r.output else 4)",
    ),
}

LIMIT = 64 * 1024
PREVIOUS = b"previous complete file\n"


def run_limited(tmp_path, name: str, kill: bool) -> subprocess.CompletedProcess:
    filename, code = WRITERS[name]
    path = tmp_path / filename
    path.write_bytes(PREVIOUS)
    script = textwrap.dedent(
        f"""
        import resource, signal, sys
        from pathlib import Path
        import numpy as np
        from plantdreamer import atomic
        rng = np.random.default_rng(0)
        path = Path({str(path)!r})
        signal.signal(signal.SIGXFSZ, signal.SIG_DFL if {kill} else signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, ({LIMIT}, {LIMIT}))
        try:
        __CODE__
        except Exception as exc:  # OSError(EFBIG), or the library's own wrapper of it
            print("raised", repr(exc))
            sys.exit(3)
        print("no error")
        """
    ).replace("__CODE__", textwrap.indent(code, "    "))
    return subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=300
    )


@pytest.mark.parametrize("name", sorted(WRITERS))
def test_write_over_the_size_limit_fails_and_keeps_the_previous_file(tmp_path, name):
    proc = run_limited(tmp_path, name, kill=False)
    assert proc.returncode == 3, proc.stdout + proc.stderr
    target = tmp_path / WRITERS[name][0]
    assert target.read_bytes() == PREVIOUS
    assert [p.name for p in tmp_path.iterdir()] == [target.name], "temporary file left"


@pytest.mark.parametrize("name", ["bytes", "png", "ply", "splat_ply", "checkpoint"])
def test_writer_killed_mid_write_keeps_the_previous_file(tmp_path, name):
    proc = run_limited(tmp_path, name, kill=True)
    assert proc.returncode < 0, proc.stdout + proc.stderr  # killed by SIGXFSZ
    assert (tmp_path / WRITERS[name][0]).read_bytes() == PREVIOUS


def test_atomic_write_replaces_and_keeps_permissions(tmp_path):
    from plantdreamer import atomic

    path = tmp_path / "a.json"
    atomic.write_json(path, {"a": 1})
    atomic.write_json(path, {"a": 2})
    assert path.read_text() == '{\n  "a": 2\n}\n'
    assert path.stat().st_mode & 0o044  # shared like any output, not mkstemp's 0600
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]
