"""Shared test helpers (pytest loads this file before the tests of this folder)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pytest

from plantdreamer.gaussians import Gaussians


def make_random_gaussians(
    n: int, degree: int = 0, seed: int = 0, *, log_scale: float | None = None
) -> Gaussians:
    """``n`` random Gaussians with SH of ``degree``.

    ``log_scale=None``: everything random (normal means, quaternions and opacity logits,
    log-scales around -4). Otherwise a tidy cloud: identity rotations, opacity 0.5 and
    log-scales ``log_scale`` + N(0, 0.05).
    """
    rng = np.random.default_rng(seed)
    f = np.float32
    k = (degree + 1) ** 2
    means = rng.normal(size=(n, 3)).astype(f)
    if log_scale is None:
        quats = rng.normal(size=(n, 4)).astype(f)
        log_scales = rng.normal(-4, 1, size=(n, 3)).astype(f)
        opacity_logits = rng.normal(size=n).astype(f)
    else:
        quats = np.zeros((n, 4), f)
        quats[:, 0] = 1
        log_scales = np.full((n, 3), log_scale, f) + rng.normal(scale=0.05, size=(n, 3)).astype(f)
        opacity_logits = np.zeros(n, f)
    sh = rng.normal(size=(n, k, 3)).astype(f)
    return Gaussians(means, quats, log_scales, opacity_logits, sh)


@pytest.fixture
def random_gaussians():
    """The ``make_random_gaussians`` factory."""
    return make_random_gaussians


# `make test` runs the suite on two pytest-xdist workers with the scheduler below (xdist's
# own `--dist loadgroup` reads markers through an attribute pytest 9 no longer uses). Each
# test file stays on one worker, so its module fixtures are made once; the files that start
# Ray (test_dataset_*.py, the only ones that may) run on one worker one after another, and
# so do the known-answer files, which share a session fixture. Those two groups, the
# largest, are handed out first.
FILE_GROUPS = {"test_dataset_": "ray", "test_known_answer_": "known_answer"}  # handed out first
SESSION_FIXTURE_GROUPS = {"shared_ray": "ray", "known_answer_plant": "known_answer"}


def file_group(nodeid: str) -> str:
    """The group of a test's file: the tests that run on one worker in turn (a file of no
    group in FILE_GROUPS is a group of its own)."""
    path = nodeid.split("::")[0]
    name = Path(path).name
    return next((g for prefix, g in FILE_GROUPS.items() if name.startswith(prefix)), path)


@pytest.hookimpl(tryfirst=True, optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    if config.getvalue("dist") != "load":  # -n alone; another --dist is left as asked
        return None
    from xdist.scheduler import LoadScopeScheduling

    class FileGroups(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return file_group(nodeid)

    config.option.loadscopereorder = False  # keep the workers' order (below)
    return FileGroups(config, log)


def pytest_collection_modifyitems(config, items):
    if hasattr(config, "workerinput"):  # an xdist worker (they collect the tests)
        rank = {group: i for i, group in enumerate(FILE_GROUPS.values())}
        items.sort(key=lambda item: rank.get(file_group(item.nodeid), len(rank)))


def pytest_runtest_setup(item):
    for fixture, group in SESSION_FIXTURE_GROUPS.items():
        if fixture in item.fixturenames and file_group(item.nodeid) != group:
            pytest.fail(
                f"{item.nodeid} uses {fixture}: its file must be in the {group} group "
                "(tests/conftest.py, FILE_GROUPS)",
                pytrace=False,
            )


@pytest.fixture(scope="module")
def bean(tmp_path_factory):
    """A small generated bean's plant folder with its label files (do not modify it)."""
    from labelled_plant import make_plant

    return make_plant(tmp_path_factory.mktemp("bean") / "plant")


@pytest.fixture(scope="session")
def shared_ray():
    """One Ray instance for the session (a 2-CPU head on 127.0.0.1, no dashboard), for the
    tests that run plants on Ray without testing how `dataset` starts and stops its own:
    they join it with ``dataset --address``. Yields the ``ray.cluster_utils.Cluster``; a test
    may add nodes to it and must remove them."""
    pytest.importorskip("ray")
    from ray.cluster_utils import Cluster

    cluster = Cluster(
        initialize_head=True,
        head_node_args={"num_cpus": 2, "include_dashboard": False,
                        "node_ip_address": "127.0.0.1"},
    )  # fmt: skip
    try:
        yield cluster
    finally:
        cluster.shutdown()


KNOWN_ANSWER_MODELS = Path(__file__).parent / "data" / "known_answer" / "bean_s0_r64"


class KnownAnswerPlant(NamedTuple):
    """The committed known-answer set's plant and its baseline: ``generate`` from noise
    colours with the trained models, scored at step 0 and at ``CHECK_STEPS``."""

    spec: Any  # known_answer.spec.KnownAnswerSpec
    truth: Any  # known_answer.check.Truth: the true Gaussians and the held-out views
    init_db: float  # masked PSNR of the noise-coloured start
    final_db: float  # after CHECK_STEPS steps of SDS with the trained models
    work: Path


@pytest.fixture(scope="session")
def known_answer_plant(tmp_path_factory) -> KnownAnswerPlant:
    """Made once for every known-answer test: the truth and the baseline runs (what each test
    compares its own runs with). Do not modify it."""
    import json

    from plantdreamer.known_answer.build import MANIFEST
    from plantdreamer.known_answer.check import Truth, step_curve
    from plantdreamer.known_answer.spec import CHECK_STEPS, KnownAnswerSpec

    work = tmp_path_factory.mktemp("known_answer")
    spec = KnownAnswerSpec(**json.loads((KNOWN_ANSWER_MODELS / MANIFEST).read_text())["spec"])
    truth = Truth.of(spec, work)
    start, end = step_curve(
        spec, truth, KNOWN_ANSWER_MODELS, work / "baseline", [0, CHECK_STEPS], color_init="noise"
    )
    return KnownAnswerPlant(spec, truth, start.masked_psnr, end.masked_psnr, work)
