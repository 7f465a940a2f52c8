"""Shared test helpers (pytest loads this file before the tests of this folder)."""

from __future__ import annotations

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


@pytest.fixture(scope="module")
def bean(tmp_path_factory):
    """A small generated bean's plant folder with its label files (do not modify it)."""
    from labelled_plant import make_plant

    return make_plant(tmp_path_factory.mktemp("bean") / "plant")
