"""Threads: OpenMP's wait policy is settled before torch loads its runtime
(thread_policy.py), and the rasterizer's pool uses every core the process may use.

libgomp prints the settings it read when it loads (OMP_DISPLAY_ENV=VERBOSE); a passive
policy shows as GOMP_SPINCOUNT 0, libgomp's default as 300000.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest


def run(code: str, **env: str) -> tuple[str, str]:
    """(OMP_WAIT_POLICY seen by the child at the end, libgomp's GOMP_SPINCOUNT)."""
    child_env = {
        k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")
    }
    child_env.update(env, OMP_DISPLAY_ENV="VERBOSE")
    code += "\nimport os; print(os.environ.get('OMP_WAIT_POLICY'))"
    out = subprocess.run(
        [sys.executable, "-c", code], env=child_env, capture_output=True, text=True, check=True
    )
    spins = [line for line in out.stderr.splitlines() if "GOMP_SPINCOUNT" in line]
    if not spins:
        pytest.skip("torch's OpenMP runtime here is not libgomp")
    return out.stdout.split()[-1], spins[0].split("=")[1].strip().strip("'")


def test_importing_plantdreamer_first_makes_torchs_openmp_workers_sleep():
    policy, spins = run("import plantdreamer, torch; torch.ones(1 << 20).sum()")
    assert (policy, spins) == ("PASSIVE", "0")


def test_the_cli_entry_point_settles_it_too():
    policy, spins = run("from plantdreamer.cli import main; import torch")
    assert (policy, spins) == ("PASSIVE", "0")


def test_torch_loaded_first_is_left_alone():
    # Too late for libgomp: the environment is not changed, so it does not claim a policy
    # the runtime never read.
    policy, spins = run("import torch, plantdreamer")
    assert (policy, spins) == ("None", "300000")


def test_a_policy_the_user_chose_is_kept():
    policy, spins = run("import plantdreamer, torch", OMP_WAIT_POLICY="ACTIVE")
    assert policy == "ACTIVE"
    assert int(spins) > 300000


def rayon_threads(**env: str) -> int:
    child_env = {k: v for k, v in os.environ.items() if k != "RAYON_NUM_THREADS"}
    child_env.update(env)
    code = "from plantdreamer import _core; print(_core.info()['threads'])"
    out = subprocess.run(
        [sys.executable, "-c", code], env=child_env, capture_output=True, text=True, check=True
    )
    return int(out.stdout)


def cpu_quota_limited() -> bool:
    """True when a cgroup CPU quota caps the process below its CPU set (rayon counts it)."""
    try:
        return not Path("/sys/fs/cgroup/cpu.max").read_text().startswith("max")
    except OSError:
        return False


def test_the_rasterizer_pool_has_one_worker_per_usable_core():
    # Not a fixed count: a many-core GPU host gets all of its cores.
    cores = len(os.sched_getaffinity(0))
    if cpu_quota_limited():
        assert 1 <= rayon_threads() <= cores
    else:
        assert rayon_threads() == cores
    assert rayon_threads(RAYON_NUM_THREADS="3") == 3
