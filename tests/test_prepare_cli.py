"""`plantdreamer prepare` on a realistic noisy plant-like cloud."""

from __future__ import annotations

import numpy as np
from click.testing import CliRunner

from plantdreamer.cli import main
from plantdreamer.cloud import PointCloud
from plantdreamer.io import read_ply, write_ply
from plantdreamer.pointcloud import NormalizeTransform
from plantdreamer.prepare import prepare_cloud


def plant_like(n: int = 120_000, seed: int = 0) -> PointCloud:
    """A stem and leaf discs in millimetres, far from the origin, with scanner noise, 2%
    uniform outliers, a few NaN rows and green colours; labels as the L-System writes them."""
    rng = np.random.default_rng(seed)
    stem = n // 5
    t = rng.uniform(0, 300, stem)
    a = rng.uniform(0, 2 * np.pi, stem)
    parts = [np.stack([3 * np.cos(a), 3 * np.sin(a), t], axis=1)]
    for i in range(8):
        m = (n - stem) // 8
        r = 40 * np.sqrt(rng.uniform(size=m))
        th = rng.uniform(0, 2 * np.pi, m)
        ang = i * 2.4
        c = np.array([45 * np.cos(ang), 45 * np.sin(ang), 40 + 30 * i])
        disc = np.stack([r * np.cos(th), 0.5 * r * np.sin(th), 0.2 * r * np.cos(th)], axis=1)
        parts.append(disc + c)
    p = np.concatenate(parts)
    p = p + rng.normal(scale=0.4, size=p.shape) + [1000.0, -2000.0, 50.0]
    k = len(p) // 50
    lo, hi = p.min(axis=0), p.max(axis=0)
    p[rng.choice(len(p), k, replace=False)] = rng.uniform(lo - 50, hi + 50, size=(k, 3))
    p[[5, 77]] = np.nan
    colors = np.clip(rng.normal([0.2, 0.6, 0.2], 0.05, size=p.shape), 0, 1)
    labels = (np.arange(len(p)) >= stem).astype(np.int64)
    return PointCloud(p.astype(np.float32), colors.astype(np.float32), attributes={"label": labels})


def test_prepare_command(tmp_path):
    src = plant_like()
    write_ply(tmp_path / "in.ply", src)
    out = tmp_path / "out.ply"
    args = ["prepare", str(tmp_path / "in.ply"), "-o", str(out), "--points", "20000", "--normalize"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    old = ["prepare", str(tmp_path / "in.ply"), "-o", str(tmp_path / "old.ply"), "--target",
           "20000", "--normalize"]  # fmt: skip  # its earlier name, still accepted
    assert CliRunner().invoke(main, old).exit_code == 0
    assert (tmp_path / "old.ply").read_bytes() == out.read_bytes()
    for step in ("input", "finite", "outliers removed", "downsampled"):
        assert step in result.output
    assert f"{len(src):>10,d}" in result.output
    cloud = read_ply(out)
    assert abs(len(cloud) - 20_000) <= 1000
    assert cloud.colors is not None and np.isfinite(cloud.positions).all()
    ext = cloud.positions.max(axis=0) - cloud.positions.min(axis=0)
    assert np.isclose(ext.max(), 4.0, rtol=1e-5)
    t = NormalizeTransform.load(tmp_path / "out.transform.json")
    back = t.invert(cloud.positions)
    finite = src.positions[np.isfinite(src.positions).all(axis=1)]
    assert (back.min(axis=0) >= finite.min(axis=0) - 1).all()
    assert (back.max(axis=0) <= finite.max(axis=0) + 1).all()


def test_prepare_removes_most_outliers():
    src = plant_like(60_000, seed=1)
    _, transform, report = prepare_cloud(src, target=None, sor_neighbors=20, sor_std=3.0)
    assert transform is None
    names = [name for name, _ in report.counts]
    assert names == ["input", "finite", "outliers removed"]
    removed = report.counts[1][1] - report.counts[2][1]
    assert 0.5 * 1200 < removed < 3 * 1200  # ~2% outliers, plus a few noisy surface points


def test_prepare_errors_are_one_line(tmp_path):
    runner = CliRunner()
    result = runner.invoke(main, ["prepare", str(tmp_path / "none.ply"), "-o", "x.ply"])
    assert result.exit_code == 1 and "error:" in result.output
    write_ply(tmp_path / "few.ply", PointCloud(np.eye(3, dtype=np.float32)))
    result = runner.invoke(main, ["prepare", str(tmp_path / "few.ply"), "-o", "x.ply"])
    assert result.exit_code == 1 and "fewer than --sor-neighbors" in result.output
    (tmp_path / "bad.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n")
    result = runner.invoke(main, ["prepare", str(tmp_path / "bad.ply"), "-o", "x.ply"])
    assert result.exit_code == 1 and "error:" in result.output


def test_points_0_keeps_a_point_cloud_whole_in_generate_as_in_prepare(tmp_path):
    """`--points 0` means one thing in both commands: every point of the cloud (after the
    outlier removal); an L-System plant, sampled by count, still needs a count."""
    import pytest

    from plantdreamer.errors import InputError
    from plantdreamer.pipeline.model.source import load_source
    from plantdreamer.pipeline.settings.config import GenerateConfig

    write_ply(tmp_path / "in.ply", plant_like(3000))
    out = tmp_path / "out.ply"
    args = ["prepare", str(tmp_path / "in.ply"), "-o", str(out), "--points", "0", "--normalize"]
    assert CliRunner().invoke(main, args).exit_code == 0
    cfg = GenerateConfig.of(pointcloud=str(tmp_path / "in.ply"), points=0)
    cfg.validate()
    source = load_source(cfg.source, cfg.seed, surface=False)
    assert "downsampled" not in source.counts
    np.testing.assert_array_equal(source.points, read_ply(out).positions)
    with pytest.raises(InputError, match="points must be a positive integer"):
        GenerateConfig.of(species="bean", points=0).validate()
