"""The local pool (``dataset`` without ``--address``): what a machine cannot run is refused
before any worker starts, GPUs are shared out as Ray would, a worker lost more often than
retried fails its plants in one line, and a driver killed outright leaves no worker
behind. The pool's plants, retries and stops beside Ray's: test_dataset_ray.py."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
from click.testing import CliRunner

from plantdreamer.cli import main
from plantdreamer.dataset.demand import Demand
from plantdreamer.dataset.local_pool import LocalPool, LocalWorker

SMALL_FLAGS = ["--guidance", "none", "--steps", "20", "--points", "2000", "--eval-views", "1",
               "--resolution", "32", "--quiet", "--allow-empty-split"]  # fmt: skip


def invoke(*args, env=None):
    return CliRunner().invoke(main, ["dataset", *map(str, args)], env=env)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--gpus-per-plant", "1"], "this machine cannot run a worker needing 1 CPU, 1 GPU "
         "(it has: 2 CPU, 0 GPU)"),
        (["--resource", "slot=1"], "needing 1 CPU, 0 GPU, 1 slot (it has: 2 CPU, 0 GPU)"),
        (["--plants-per-gpu", "4"], "needing 4 CPU, 0 GPU"),
        (["--cpus-per-plant", "3"], "needing 3 CPU"),
    ],
)  # fmt: skip
def test_what_this_machine_cannot_run_is_refused_before_any_worker_starts(
    tmp_path, monkeypatch, args, message
):
    from plantdreamer.dataset import runner

    monkeypatch.setattr(runner, "open_workers", lambda *a: pytest.fail("workers started"))
    result = invoke("--species", "bean", "--seeds", "0-3", "--local-cpus", 2, *SMALL_FLAGS,
                    *args, "--out", tmp_path / "d", env={"CUDA_VISIBLE_DEVICES": ""})  # fmt: skip
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert result.exit_code == 1 and len(errors) == 1, result.output
    assert message in errors[0] and "--address" in errors[0], errors
    assert not (tmp_path / "d" / "plants").exists()


def test_gpus_are_shared_out_as_ray_shares_them():
    """Fractions of one GPU share it; a worker of 2 GPUs takes two whole ones; one that
    does not fit waits (nothing is started here: only the books are kept)."""
    pool = LocalPool(8, ["0", "1", "2"])

    def take(gpus):
        worker = LocalWorker(Demand(1.0, gpus), 0, {})
        return worker.gpus if pool._take(worker) else None

    assert [take(0.5), take(0.5), take(0.5)] == [["0"], ["0"], ["1"]]
    assert take(2) is None  # GPU 1 is half taken: one whole GPU left
    assert take(1) == ["2"] and take(0) == [] and take(0.5) == ["1"]
    assert pool.free_cpus == 2 and take(0.5) is None  # the GPUs are all taken
    worker = LocalWorker(Demand(6.0, 0.0), 0, {})
    assert not pool._take(worker)  # 2 CPUs left
    assert LocalPool(2, []).capacity(Demand(1.0, 0.0)) == 2
    assert LocalPool(2, ["0"]).capacity(Demand(2.0, 1.0)) == 1


def manifest(out):
    return {r["id"]: r for r in map(json.loads, (out / "manifest.jsonl").read_text().splitlines())}


def driver(out, *extra, hold=None):
    env = {**os.environ, **({"PLANTDREAMER_DATASET_HOLD": hold} if hold else {})}
    cmd = [sys.executable, "-m", "plantdreamer.cli", "dataset", "--species", "bean", "--seeds",
           "0-1", "--set", "checkpoint-every=5", *SMALL_FLAGS, *extra, "--out", str(out)]  # fmt: skip
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)  # fmt: skip


def wait_for(condition, proc, what, timeout=300):
    deadline = time.time() + timeout
    while not condition():
        assert proc.poll() is None and time.time() < deadline, what
        time.sleep(0.5)


@pytest.mark.slow
def test_a_worker_lost_more_often_than_retried_fails_its_plant_in_one_line(tmp_path):
    out = tmp_path / "out"
    proc = driver(out, "--max-retries", "0", hold="bean-s0001:12")
    try:
        log = out / "plants" / "bean-s0001" / "generate.log"
        wait_for(lambda: log.is_file() and "holding after step 12" in log.read_text(), proc,
                 "the plant never reached step 12")  # fmt: skip
        pid = manifest(out)["bean-s0001"]["pid"]
        os.kill(pid, signal.SIGKILL)
        output, _ = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=120)
    assert proc.returncode == 1, output
    assert "error: 1 of 2 plants failed" in output and "Traceback" not in output, output
    record = manifest(out)["bean-s0001"]
    assert record["status"] == "failed"
    assert record["error"] == f"WorkerDied: the worker process (pid {pid}) was killed by SIGKILL"
    assert manifest(out)["bean-s0000"]["status"] == "done"


@pytest.mark.slow
def test_a_driver_killed_outright_leaves_no_worker_and_its_plants_resume(tmp_path):
    """SIGKILL gives the driver no chance to stop its workers: each gets SIGTERM from the
    kernel (their parent died), writes its checkpoint and exits; a rerun resumes them."""
    import psutil

    out = tmp_path / "out"
    proc = driver(out, "--steps", "100000")
    try:
        checkpoints = [out / "plants" / f"bean-s000{i}" / "checkpoint.pt" for i in (0, 1)]
        wait_for(lambda: all(c.is_file() for c in checkpoints), proc, "the plants never started")
        workers = {r["pid"] for r in manifest(out).values()}
        assert proc.pid not in workers and len(workers) == 2
        proc.kill()
        proc.wait(timeout=30)
        deadline = time.time() + 120
        while any(psutil.pid_exists(p) for p in workers) and time.time() < deadline:
            time.sleep(0.5)
        assert not [p for p in workers if psutil.pid_exists(p)], "workers outlived their driver"
    finally:
        if proc.poll() is None:
            proc.kill()
    again = invoke("--species", "bean", "--seeds", "0-1", "--set", "checkpoint-every=5",
                   *SMALL_FLAGS, "--steps", "100000", "--dry-run", "--out", out)  # fmt: skip
    assert again.exit_code == 0, again.output
    assert "0 make, 2 resume, 0 skip, 0 redo" in again.output
