"""A folder a run holds is in use down to its last file: a command writing inside it is
refused, having written nothing, and a second ``generate`` into it is told it is in use.

"Another run" is a lock taken on its own open file (``flock`` locks belong to an open
file, so a second open in this process conflicts as another process's would), with a token
that is not this process's; the slow test holds it from a real second process.
"""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys
import time
from contextlib import contextmanager

import numpy as np
import pytest

from cli_run import one_error, run
from plantdreamer.cloud import PointCloud
from plantdreamer.io import write_ply, write_splat_ply
from plantdreamer.output_folder import LOCK_NAME, claim_folder
from plantdreamer.output_locks import HELD_ENV
from plantdreamer.pipeline.model.init import init_gaussians


@contextmanager
def held_by_another_run(folder, token="another-run"):
    """``folder``'s lock, taken as another process takes it."""
    folder.mkdir(parents=True, exist_ok=True)
    fd = os.open(folder / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o666)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    os.write(fd, token.encode())
    try:
        yield
    finally:
        (folder / LOCK_NAME).unlink(missing_ok=True)
        os.close(fd)


def snapshot(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != LOCK_NAME}  # fmt: skip


@pytest.fixture
def plant(tmp_path):
    """A finished plant's folder (its model and point cloud)."""
    folder = tmp_path / "plant"
    folder.mkdir()
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(200, 3)).astype(np.float32)
    write_splat_ply(folder / "plant.ply", init_gaussians(pts, None, 0.5))
    write_ply(folder / "points.ply", PointCloud(pts))
    write_ply(tmp_path / "cloud.ply", PointCloud(pts))
    return folder


def test_render_inside_a_held_plant_is_refused(plant):
    before = snapshot(plant)
    with held_by_another_run(plant):
        args = ["render", plant / "plant.ply", "--out", plant / "renders", "--eval-views", 1,
                "--resolution", 16, "--turntable", "none"]  # fmt: skip
        one_error(run(*args), "in use by another plantdreamer run")
        assert snapshot(plant) == before and not (plant / "renders").exists()
    assert run(*args).exit_code == 0  # once the run is over


def test_prepare_into_a_held_plant_is_refused(plant, tmp_path):
    before = snapshot(plant)
    args = ["prepare", tmp_path / "cloud.ply", "-o", plant / "points.ply", "--points", 0,
            "--sor-neighbors", 0, "--overwrite"]  # fmt: skip
    with held_by_another_run(plant):
        one_error(run(*args), "in use by another plantdreamer run")
        # two levels down too
        one_error(run(*args[:3], plant / "a" / "b" / "p.ply", *args[4:]), "in use")
    assert snapshot(plant) == before and not (plant / "a").exists()


def test_a_second_generate_is_told_the_folder_is_in_use(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "checkpoint.pt").write_bytes(b"the running run's checkpoint")
    with held_by_another_run(out):
        result = run("generate", "--species", "bean", "--guidance", "none", "--out", out)
        one_error(result, "in use by another plantdreamer run")
        assert "--resume" not in result.output


def test_locks_this_process_holds_or_was_handed_are_its_own(tmp_path, monkeypatch):
    outer = tmp_path / "group"
    with claim_folder(outer), claim_folder(outer / "plant"):  # a group's plant: same process
        pass
    with held_by_another_run(outer, token="the-dataset-driver"):
        with pytest.raises(Exception, match="in use"), claim_folder(outer / "plant"):
            pass
        monkeypatch.setenv(HELD_ENV, "x,the-dataset-driver")  # a dataset's worker
        with claim_folder(outer / "plant"):
            pass


@pytest.mark.slow
def test_a_run_in_another_process_holds_the_folder_below_it(plant, tmp_path):
    code = (
        "import sys, time\n"
        "from pathlib import Path\n"
        "from plantdreamer.output_folder import claim_folder\n"
        "with claim_folder(Path(sys.argv[1]), allow_existing=True):\n"
        "    print('held', flush=True)\n"
        "    time.sleep(60)\n"
    )
    holder = subprocess.Popen([sys.executable, "-c", code, str(plant)], stdout=subprocess.PIPE,
                              text=True)  # fmt: skip
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        args = ["render", plant, "--out", plant / "renders", "--eval-views", 1,
                "--resolution", 16, "--turntable", "none"]  # fmt: skip
        proc = subprocess.run([sys.executable, "-m", "plantdreamer", *map(str, args)],
                              capture_output=True, text=True, timeout=120)  # fmt: skip
        assert proc.returncode == 1 and "in use by another plantdreamer run" in proc.stderr
        assert not (plant / "renders").exists()
    finally:
        holder.kill()
        holder.wait()
    deadline = time.time() + 10  # the kernel drops a killed holder's lock
    while run(*args).exit_code != 0 and time.time() < deadline:
        time.sleep(0.2)
    assert (plant / "renders").is_dir()
