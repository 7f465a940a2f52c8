"""Point-cloud kernels against plain float64 numpy references (and Open3D 0.20 when it
is installed: the `bench` extra)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plantdreamer import pointcloud as pc
from plantdreamer.errors import InputError


def noisy_shell(n: int, seed: int = 0, outliers: float = 0.03) -> tuple[np.ndarray, np.ndarray]:
    """A plant-sized noisy surface (ellipsoid shell) with uniform outliers and colours."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    p = v * [0.3, 0.2, 0.6] + rng.normal(scale=0.005, size=(n, 3))
    m = int(n * outliers)
    p[:m] = rng.uniform(-0.8, 0.8, size=(m, 3))
    return p.astype(np.float32), rng.uniform(size=(n, 3)).astype(np.float32)


def sq_dist(p: np.ndarray) -> np.ndarray:
    q = p.astype(np.float64)
    d = q[:, None, :] - q[None, :, :]
    return (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]) + d[..., 2] * d[..., 2]


def sor_reference(p: np.ndarray, k: int, ratio: float) -> np.ndarray:
    """Open3D 0.20's algorithm, written out in dense float64."""
    d = np.sort(np.sqrt(sq_dist(p)), axis=1)[:, :k]
    score = np.cumsum(d, axis=1)[:, -1] / k  # sequential sum, nearest first
    n = len(p)
    pos = score > 0
    mean = np.cumsum(np.where(pos, score, 0.0))[-1] / n
    std = np.sqrt(np.cumsum(np.where(pos, (score - mean) ** 2, 0.0))[-1] / (n - 1))
    return np.flatnonzero(pos & (score < mean + ratio * std))


def voxel_reference(p: np.ndarray, v: float, colors: np.ndarray):
    q = p.astype(np.float64)
    origin = q.min(axis=0) - v * 0.5
    acc: dict[tuple[int, int, int], list] = {}
    for i in range(len(q)):
        key = tuple(int(x) for x in np.floor((q[i] - origin) / v))
        a = acc.setdefault(key, [np.zeros(3), np.zeros(3), 0])
        a[0] = a[0] + q[i]
        a[1] = a[1] + colors[i].astype(np.float64)
        a[2] += 1
    keys = sorted(acc)
    pts = np.array([acc[k][0] / acc[k][2] for k in keys])
    cols = np.array([acc[k][1] / acc[k][2] for k in keys]).astype(np.float32)
    return pts, cols


@pytest.mark.parametrize(("k", "ratio"), [(20, 2.0), (8, 1.0), (20, 3.0), (2, 2.0)])
def test_sor_matches_reference(k, ratio):
    p, _ = noisy_shell(1500, seed=k)
    kept = pc.remove_statistical_outliers(p, k, ratio)
    assert kept.dtype == np.int64
    np.testing.assert_array_equal(kept, sor_reference(p, k, ratio))
    assert 0 < len(kept) < len(p)


def test_sor_with_duplicates_and_float64():
    p, _ = noisy_shell(800, seed=5)
    dup = np.concatenate([p, np.repeat(p[:3], 25, axis=0)]).astype(np.float64)
    kept = pc.remove_statistical_outliers(dup, 20, 2.0)
    np.testing.assert_array_equal(kept, sor_reference(dup, 20, 2.0))
    assert not np.isin(np.arange(800, len(dup)), kept).any()  # duplicates score 0


def test_thousands_of_identical_points():
    p = np.ones((5000, 3), np.float32)
    assert len(pc.remove_statistical_outliers(p, 20, 2.0)) == 0
    idx, d = pc.knn(p, 20)
    assert (d == 0).all() and (idx != np.arange(5000)[:, None]).all()
    out, _ = pc.voxel_downsample(p, 0.1)
    np.testing.assert_array_equal(out, [[1, 1, 1]])


def test_voxel_matches_reference_and_is_sorted():
    p, c = noisy_shell(4000, seed=2)
    for v in (0.02, 0.05, 0.3):
        got_p, got_c = pc.voxel_downsample(p, v, c)
        ref_p, ref_c = voxel_reference(p, v, c)
        assert got_p.dtype == np.float32 and got_c.dtype == np.float32
        np.testing.assert_array_equal(got_p, ref_p.astype(np.float32))
        np.testing.assert_array_equal(got_c, ref_c)
        got64, none = pc.voxel_downsample(p.astype(np.float64), v)
        assert none is None
        np.testing.assert_array_equal(got64, ref_p)


def test_knn_matches_brute_force():
    p, _ = noisy_shell(700, seed=3)
    idx, d = pc.knn(p, 6)
    assert idx.shape == d.shape == (700, 6) and idx.dtype == np.int64 and d.dtype == np.float32
    full = np.sqrt(sq_dist(p))
    np.fill_diagonal(full, np.inf)
    ref = np.sort(full, axis=1)[:, :6]
    np.testing.assert_array_equal(d, ref.astype(np.float32))
    np.testing.assert_array_equal(full[np.arange(700)[:, None], idx].astype(np.float32), d)
    order = np.argsort(full, axis=1, kind="stable")[:, :6]
    np.testing.assert_array_equal(idx, order)  # no ties in random data
    m = pc.knn_mean_distance(p, 3)
    np.testing.assert_allclose(m, ref[:, :3].mean(axis=1), rtol=1e-6)
    assert m.dtype == np.float32


def test_threads_do_not_change_results():
    p, c = noisy_shell(30_000, seed=4)
    for f in (
        lambda t: pc.remove_statistical_outliers(p, 20, 2.0, threads=t),
        lambda t: pc.voxel_downsample(p, 0.01, c, threads=t),
        lambda t: pc.knn(p, 5, threads=t),
        lambda t: pc.downsample_to_count(p, 5000, c, threads=t),
    ):
        a, b = f(1), f(2)
        a, b = (a, b) if isinstance(a, tuple) else ((a,), (b,))
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("target", [500, 3000, 10_000])
def test_downsample_to_count_lands_in_band(target):
    p, c = noisy_shell(40_000, seed=6)
    out, cols, v = pc.downsample_to_count(p, target, c)
    assert abs(len(out) - target) <= 0.05 * target
    assert v > 0 and len(cols) == len(out)
    same, _ = pc.voxel_downsample(p, v, c)
    np.testing.assert_array_equal(out, same)


def test_downsample_to_count_small_input_is_unchanged():
    p, c = noisy_shell(1000)
    out, cols, v = pc.downsample_to_count(p, 1000, c)
    assert v == 0.0
    np.testing.assert_array_equal(out, p)
    np.testing.assert_array_equal(cols, c)


def test_normalize_and_invert():
    p, _ = noisy_shell(1000)
    p = p * 7 + np.float32(100)
    out, t = pc.normalize(p)
    assert out.dtype == np.float32
    ext = p.max(axis=0).astype(np.float64) - p.min(axis=0)
    np.testing.assert_allclose(out.max(axis=0) - out.min(axis=0), ext * 4 / ext.max(), rtol=1e-5)
    np.testing.assert_allclose(t.center, (p.max(axis=0) + p.min(axis=0).astype(np.float64)) / 2)
    np.testing.assert_allclose((out.max(axis=0) + out.min(axis=0)) / 2, 0, atol=1e-5)
    assert np.isclose((out.max(axis=0) - out.min(axis=0)).max(), 4.0)
    np.testing.assert_allclose(t.invert(out), p, rtol=1e-6)
    assert pc.NormalizeTransform.from_dict(t.to_dict()) == t
    with pytest.raises(dataclasses.FrozenInstanceError):
        t.scale = 2.0  # type: ignore[misc]


@pytest.mark.parametrize(
    ("call", "needle"),
    [
        (lambda: pc.remove_statistical_outliers(np.zeros((0, 3), np.float32)), "empty"),
        (lambda: pc.remove_statistical_outliers(np.zeros((5, 3), np.float32), 20), "fewer"),
        (lambda: pc.remove_statistical_outliers(np.eye(3, dtype=np.float32), 2, -1.0), "std_ratio"),
        (lambda: pc.remove_statistical_outliers(np.full((30, 3), np.nan), 20), "non-finite"),
        (lambda: pc.knn(np.eye(3), 3), "too few"),
        (lambda: pc.knn(np.zeros((4, 2)), 1), r"\[N, 3\]"),
        (lambda: pc.knn(np.array([[0, 0, np.inf], [1, 1, 1]]), 1), "non-finite"),
        (lambda: pc.voxel_downsample(np.eye(3), 0.0), "positive"),
        (lambda: pc.voxel_downsample(np.eye(3), -1.0), "positive"),
        (lambda: pc.voxel_downsample(np.eye(3), 1e-12), "overflow"),
        (lambda: pc.voxel_downsample(np.eye(3), 0.1, np.zeros((2, 3))), "colors"),
        (lambda: pc.downsample_to_count(np.ones((500, 3)), 10), "identical"),
        (lambda: pc.normalize(np.ones((5, 3))), "identical"),
        (lambda: pc.normalize(np.zeros((0, 3))), "non-empty"),
    ],
)
def test_bad_input_raises_input_error(call, needle):
    with pytest.raises(InputError, match=needle):
        call()


def test_non_contiguous_and_other_dtypes_are_accepted():
    p, _ = noisy_shell(300)
    wide = np.zeros((300, 6), np.float32)
    wide[:, ::2] = p
    np.testing.assert_array_equal(pc.knn(wide[:, ::2], 2)[1], pc.knn(p, 2)[1])
    ints = np.arange(30).reshape(10, 3)
    assert pc.knn(ints, 1)[1].dtype == np.float32


def test_open3d_identical_kept_set_and_voxels():
    o3d = pytest.importorskip("open3d")
    p, c = noisy_shell(20_000, seed=9)
    p = np.concatenate([p, np.repeat(p[:2], 30, axis=0)])  # duplicates: scores of 0
    c = np.concatenate([c, np.repeat(c[:2], 30, axis=0)])
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p.astype(np.float64)))
    cloud.colors = o3d.utility.Vector3dVector(c.astype(np.float64))
    for k, ratio in [(20, 2.0), (10, 1.0), (20, 3.0)]:
        _, ref = cloud.remove_statistical_outlier(nb_neighbors=k, std_ratio=ratio)
        np.testing.assert_array_equal(pc.remove_statistical_outliers(p, k, ratio), np.sort(ref))
    for v in (0.01, 0.037):
        down = cloud.voxel_down_sample(v)
        ref_p, ref_c = np.asarray(down.points), np.asarray(down.colors)
        got_p, got_c = pc.voxel_downsample(p.astype(np.float64), v, c)
        assert len(got_p) == len(ref_p)
        order = np.lexsort(np.floor((ref_p - (p.min(axis=0) - v / 2)) / v).T[::-1])
        np.testing.assert_array_equal(got_p, ref_p[order])
        np.testing.assert_array_equal(got_c, ref_c[order].astype(np.float32))


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(2, 250),
    k=st.integers(1, 30),
    ratio=st.floats(0.1, 4.0),
    dup=st.integers(0, 40),
    grid=st.booleans(),
    seed=st.integers(0, 2**32 - 1),
)
def test_sor_and_voxel_properties(n, k, ratio, dup, grid, seed):
    """Random small clouds, with duplicates and lattice points (ties), against the references."""
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    if grid:
        p = np.round(p * 2) / 2  # many equal coordinates and equal distances
    p = np.concatenate([p, np.repeat(p[:1], dup, axis=0)]).astype(np.float32)
    c = rng.uniform(size=(len(p), 3)).astype(np.float32)
    if k > len(p):
        with pytest.raises(InputError):
            pc.remove_statistical_outliers(p, k, ratio)
    else:
        np.testing.assert_array_equal(
            pc.remove_statistical_outliers(p, k, ratio), sor_reference(p, k, ratio)
        )
    v = float(rng.uniform(0.05, 2.0))
    got_p, got_c = pc.voxel_downsample(p, v, c)
    ref_p, ref_c = voxel_reference(p, v, c)
    np.testing.assert_array_equal(got_p, ref_p.astype(np.float32))
    np.testing.assert_array_equal(got_c, ref_c)
    if len(p) > 3:
        _, d = pc.knn(p, 3)
        full = np.sqrt(sq_dist(p))
        np.fill_diagonal(full, np.inf)
        np.testing.assert_array_equal(d, np.sort(full, axis=1)[:, :3].astype(np.float32))


def test_gaussians_move_with_the_transform_and_back(random_gaussians):
    """One similarity transform for Gaussians: means by ``apply`` / ``invert``, every
    log-scale by log(scale), everything else copied (export and ``render`` use it)."""
    g = random_gaussians(50)
    t = pc.NormalizeTransform(center=(1.0, -2.0, 0.5), scale=0.25)
    scene = t.gaussians_to_scene(g)
    np.testing.assert_array_equal(
        scene.means, t.apply(g.means.astype(np.float64)).astype(np.float32)
    )
    np.testing.assert_allclose(scene.log_scales, g.log_scales + np.log(0.25), atol=1e-6)
    assert np.array_equal(scene.quats, g.quats) and scene.quats is not g.quats
    back = t.gaussians_to_original(scene, offset=np.array([1.0, 0.0, 0.0]))
    np.testing.assert_allclose(back.means, g.means - [1.0, 0.0, 0.0], atol=1e-5)
    np.testing.assert_allclose(back.log_scales, g.log_scales, atol=1e-6)
    np.testing.assert_array_equal(back.sh, g.sh)
