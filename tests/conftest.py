"""Shared test helpers (pytest loads this file before the tests of this folder)."""

from __future__ import annotations

import os
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


# `make test-python` runs the suite in two steps, on public pytest and pytest-xdist behaviour
# only (xdist's `--dist loadgroup` reads marks through a node id that pytest 9 no longer
# uses). First the two largest groups, side by side, each in one pytest process of its own:
# the files that start Ray (test_dataset_*.py, the only ones that may), one after another, and
# the known-answer files, which share a session fixture. Then every other file on xdist
# workers, `--dist loadfile` (pyproject's addopts): each file on one worker, so its module
# fixtures are made once. `--file-group NAME` picks a group's files (`other`: the rest).
FILE_GROUPS = {"test_dataset_": "ray", "test_known_answer_": "known_answer"}
SESSION_FIXTURE_GROUPS = {"shared_ray": "ray", "known_answer_plant": "known_answer"}
OTHER = "other"  # --file-group of the files in no group


def file_group(nodeid: str) -> str:
    """The group of a test's file (a node id or a file path): FILE_GROUPS' or OTHER."""
    name = Path(nodeid.split("::")[0]).name
    return next((g for prefix, g in FILE_GROUPS.items() if name.startswith(prefix)), OTHER)


def pytest_addoption(parser):
    parser.addoption(
        "--file-group",
        choices=(*FILE_GROUPS.values(), OTHER),
        help="Only the test files of this group (tests/conftest.py: FILE_GROUPS; other: the "
        "files of none); `make test-python` runs each.",
    )


def pytest_ignore_collect(collection_path, config):
    wanted = config.getoption("file_group")
    if wanted is not None and collection_path.suffix == ".py":
        if collection_path.name.startswith("test_") and file_group(str(collection_path)) != wanted:
            return True
    return None  # the other hooks decide


def pytest_collection_modifyitems(config, items):
    wanted = config.getoption("file_group")  # files named on the command line are collected
    if wanted is not None:
        other = [item for item in items if file_group(item.nodeid) != wanted]
        if other:
            config.hook.pytest_deselected(items=other)
            items[:] = [item for item in items if file_group(item.nodeid) == wanted]


def pytest_runtest_setup(item):
    group = file_group(item.nodeid)
    for fixture, fixture_group in SESSION_FIXTURE_GROUPS.items():
        if fixture in item.fixturenames and group != fixture_group:
            pytest.fail(
                f"{item.nodeid} uses {fixture}: its file must be in the {fixture_group} group "
                "(tests/conftest.py, FILE_GROUPS)",
                pytrace=False,
            )
    # Several xdist workers could run two files of a group at once (two Rays; the session
    # fixture made twice): a group runs in a process of its own.
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if group != OTHER and workers > 1 and len(_group_files(item.session, group)) > 1:
        pytest.fail(
            f"the {group} files run one after another in one process: run them with "
            f"`--file-group {group}` and no -n, as `make test-python` does",
            pytrace=False,
        )


def _group_files(session, group: str) -> set[str]:
    return {
        item.nodeid.split("::")[0] for item in session.items if file_group(item.nodeid) == group
    }


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
