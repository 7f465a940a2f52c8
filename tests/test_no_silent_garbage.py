"""Inputs that used to give wrong output with exit 0: each is now an error or a repair that
says what it did."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from plantdreamer.cli import main
from plantdreamer.cloud import PointCloud
from plantdreamer.errors import InputError
from plantdreamer.io import read_ply, read_ply_columns, read_splat_ply, write_ply
from plantdreamer.pointcloud import normalize


def cloud(n=600, seed=0, offset=(0.0, 0.0, 0.0), dtype=np.float32):
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(n, 3)) * [0.1, 0.1, 0.3] + np.asarray(offset)
    return PointCloud(pts.astype(dtype), colors=rng.random((n, 3), dtype=np.float32))


def test_nan_colours_are_dropped_with_a_warning(tmp_path):
    c = cloud()
    c.colors[[3, 30, 300]] = np.nan
    write_ply(tmp_path / "in.ply", c, color_dtype="float")
    result = CliRunner().invoke(
        main, ["prepare", str(tmp_path / "in.ply"), "-o", str(tmp_path / "out.ply"),
               "--points", "0", "--sor-neighbors", "0"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "warning: 3 of 600 points have NaN or Inf colours; those points were dropped" in (
        result.output
    )
    out = read_ply(tmp_path / "out.ply")
    assert len(out) == 597 and np.isfinite(out.colors).all()


@pytest.mark.parametrize(
    ("dtype", "span"), [(np.float32, 3.0e38), (np.float64, 1.5e308)], ids=["float32", "float64"]
)
def test_normalize_a_cloud_whose_extent_overflows(dtype, span):
    pts = np.array([[-span, 0, 0], [span, 1, 0], [0, -span, span]], dtype=dtype)
    moved, t = normalize(pts, size=4.0)
    assert np.isfinite(moved).all() and t.scale > 0
    np.testing.assert_allclose(np.abs(moved).max(), 2.0, rtol=1e-6)
    np.testing.assert_allclose(t.invert(moved.astype(np.float64)), pts, atol=span * 1e-6)


def test_normalize_refuses_an_extent_too_small_to_scale():
    pts = np.array([[0.0, 0.0, 0.0], [1e-310, 0.0, 0.0]])
    with pytest.raises(InputError, match="cannot be scaled"):
        normalize(pts)


def test_georeferenced_plant_keeps_its_precision(tmp_path):
    """A plant 20 cm tall at UTM-like coordinates: float32 in the input frame would keep
    only a few distinct values; the export is relative to an offset recorded in run.json
    and in the PLY header."""
    from plantdreamer.pipeline import GenerateConfig, generate_plants

    utm = (500_000.0, 5_000_000.0, 200.0)
    write_ply(tmp_path / "scan.ply", cloud(3000, offset=utm, dtype=np.float64))
    cfg = GenerateConfig.of(pointcloud=str(tmp_path / "scan.ply"), guidance="none", steps=0,
                         points=5000, sor_std=100.0, resolution=32, eval_views=1,
                         turntable_frames=1)  # fmt: skip
    result = generate_plants([cfg], tmp_path / "o", show_progress=False)[0]
    run = json.loads((tmp_path / "o" / "run.json").read_text())
    offset = np.asarray(run["export_offset"])
    np.testing.assert_allclose(offset, utm, atol=1.0)
    header = (tmp_path / "o" / "plant.ply").read_bytes().split(b"end_header")[0].decode()
    assert "comment plantdreamer offset 500000 5000000 200" in header
    g = read_splat_ply(result.ply_path)
    source = read_ply(tmp_path / "scan.ply").positions
    restored = g.means.astype(np.float64) + offset
    assert len(np.unique(g.means[:, 1])) > 1000  # not quantised to a handful of values
    np.testing.assert_allclose(restored.min(0), source.min(0), atol=1e-4)
    np.testing.assert_allclose(restored.max(0), source.max(0), atol=1e-4)


def test_plant_near_the_origin_has_no_offset(tmp_path):
    from plantdreamer.pipeline import GenerateConfig, generate_plants

    cfg = GenerateConfig.of(species="kale", guidance="none", steps=0, points=500, resolution=32,
                         eval_views=1, turntable_frames=1)  # fmt: skip
    generate_plants([cfg], tmp_path / "o", show_progress=False)
    assert json.loads((tmp_path / "o" / "run.json").read_text())["export_offset"] is None
    assert b"offset" not in (tmp_path / "o" / "plant.ply").read_bytes()[:2000]


def test_prepare_points_above_the_point_count_keeps_every_point(tmp_path):
    write_ply(tmp_path / "in.ply", cloud(300))
    result = CliRunner().invoke(
        main, ["prepare", str(tmp_path / "in.ply"), "-o", str(tmp_path / "o.ply"),
               "--points", str(10**20), "--sor-neighbors", "0"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert len(read_ply_columns(tmp_path / "o.ply")["x"]) == 300


def test_lsystem_huge_point_count_is_one_error_line(tmp_path):
    result = CliRunner().invoke(
        main, ["lsystem", "bean", "--points", str(10**11), "-o", str(tmp_path / "x.ply")]
    )
    assert result.exit_code == 1 and "above the limit" in result.output
    assert "Traceback" not in result.output


@pytest.mark.parametrize("n", [3.7, 2.0, True, "5"])
def test_sample_points_refuses_non_integer_counts(n):
    from plantdreamer.lsystem import generate_plant, sample_points

    with pytest.raises(InputError, match="positive integer"):
        sample_points(generate_plant("kale", 0), n=n)


def test_guidance_none_progress_says_what_the_run_does(tmp_path):
    result = CliRunner().invoke(
        main, ["generate", "--species", "kale", "--guidance", "none", "--steps", "4",
               "--points", "500", "--resolution", "32", "--eval-views", "1",
               "--out", str(tmp_path / "o")],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "no training: density control and culling only" in result.output
    assert "initialised" in result.output and "exporting" in result.output
    assert "loss 0" not in result.output and "it/s" not in result.output
    # The export counts its views, then says it writes the label files: never silent.
    assert "export: views 1/1" in result.output and "export: label files" in result.output


def test_a_counter_prints_each_tenth_and_nothing_when_disabled(capsys):
    from plantdreamer.pipeline.progress import Counter

    with Counter("render: views", 25) as counter:
        for _ in range(25):
            counter.advance()
    lines = capsys.readouterr().err.splitlines()
    assert lines == [f"render: views {k}/25" for k in (2, 4, 6, 8, 10, 12, 14, 16, 18, 20,
                                                         22, 24, 25)]  # fmt: skip
    with Counter("quiet", 5, enabled=False) as counter:
        counter.advance()
    assert capsys.readouterr().err == ""


def test_render_counts_its_views(tmp_path):
    out = tmp_path / "o"
    made = CliRunner().invoke(
        main, ["generate", "--species", "kale", "--guidance", "none", "--steps", "0",
               "--points", "300", "--resolution", "32", "--eval-views", "1", "--quiet",
               "--out", str(out)],
    )  # fmt: skip
    assert made.exit_code == 0, made.output
    result = CliRunner().invoke(
        main, ["render", str(out / "plant.ply"), "--out", str(tmp_path / "r"), "--eval-views",
               "3", "--resolution", "32", "--turntable", "none"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "render: views 3/3" in result.output


# --- render framing -------------------------------------------------------------------------


def _scene_with_floaters(up_axis=2):
    """A dense unit blob at (10, 10, 10) plus two far, opaque floaters."""
    from plantdreamer.pipeline.model.init import init_gaussians

    rng = np.random.default_rng(0)
    blob = rng.normal(size=(2000, 3)) * 0.2
    blob[:, up_axis] *= 3.0  # tall along the up axis
    pts = np.concatenate([blob + 10.0, [[1e4, 0, 0], [-1e4, 5e3, 0]]]).astype(np.float32)
    colors = np.tile(np.float32([0.2, 0.6, 0.2]), (len(pts), 1))
    return init_gaussians(pts, colors, 0.9)


def test_robust_frame_ignores_floaters():
    from plantdreamer.framing import to_scene_frame

    framed, _ = to_scene_frame(_scene_with_floaters())
    core = framed.means[:-2]
    assert np.abs(np.median(core, axis=0)).max() < 0.05  # centred on the blob
    assert 2.0 < np.ptp(core, axis=0).max() < 8.0  # the blob fills the frame, not 1e-4 of it


@pytest.mark.parametrize(("up", "axis", "sign"), [("y", 1, 1), ("-y", 1, -1), ("x", 0, 1),
                                                  ("-x", 0, -1), ("-z", 2, -1)])  # fmt: skip
def test_up_axis_becomes_z(up, axis, sign):
    from plantdreamer.framing import UP_AXES, rotate_up
    from plantdreamer.gaussians import Gaussians

    rotation, _ = UP_AXES[up]
    assert np.allclose(rotation @ rotation.T, np.eye(3)) and np.isclose(np.linalg.det(rotation), 1)
    v = np.zeros(3)
    v[axis] = sign
    assert np.allclose(rotation @ v, [0, 0, 1])
    # The quaternion is the same rotation: rotating an axis-aligned Gaussian's quaternion.
    g = Gaussians(
        np.array([v], np.float32), np.array([[1, 0, 0, 0]], np.float32),
        np.zeros((1, 3), np.float32), np.zeros(1, np.float32), np.zeros((1, 1, 3), np.float32),
    )  # fmt: skip
    turned = rotate_up(g, up)
    assert np.allclose(turned.means, [[0, 0, 1]], atol=1e-6)
    w, x, y, z = turned.quats[0].astype(np.float64)
    r = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip
    assert np.allclose(r, rotation, atol=1e-6)


def test_render_with_up_center_and_old_views_name(tmp_path):
    from plantdreamer.io import write_splat_ply

    write_splat_ply(tmp_path / "m.ply", _scene_with_floaters(up_axis=1))
    args = ["render", str(tmp_path / "m.ply"), "--resolution", "32", "--turntable", "none",
            "--up", "y", "--center", "10,10,10"]  # fmt: skip
    new = CliRunner().invoke(main, [*args, "--eval-views", "2", "--out", str(tmp_path / "a")])
    old = CliRunner().invoke(main, [*args, "--views", "2", "--out", str(tmp_path / "b")])
    assert new.exit_code == 0 and old.exit_code == 0, new.output + old.output
    import imageio.v3 as iio

    for name in ("view_000.png", "view_001.png"):
        a = iio.imread(tmp_path / "a" / name)
        assert np.array_equal(a, iio.imread(tmp_path / "b" / name))
        assert (np.abs(a.astype(int) - 191).max(axis=-1) > 20).mean() > 0.05  # subject visible
    bad = CliRunner().invoke(main, [*args[:-2], "--center", "1,2", "--out", str(tmp_path / "c")])
    assert bad.exit_code == 1 and "--center" in bad.output


def _api_calls():
    import torch

    from plantdreamer import pointcloud, rasterization
    from plantdreamer.cameras import Camera
    from plantdreamer.io import write_splat_ply
    from plantdreamer.pipeline.model.init import init_gaussians

    pts = np.random.default_rng(0).random((50, 3), dtype=np.float32)
    g = init_gaussians(pts, np.full((50, 3), 0.5, np.float32), 0.5)
    t = torch.from_numpy
    return {
        "knn k": lambda: pointcloud.knn(pts, 2.5),
        "knn_mean_distance k": lambda: pointcloud.knn_mean_distance(pts, 2.5),
        "sor neighbours": lambda: pointcloud.remove_statistical_outliers(pts, 4.5),
        "downsample target": lambda: pointcloud.downsample_to_count(pts, 10.5),
        "sh degree": lambda: g.with_sh_degree(2.5),
        "export sh degree": lambda: write_splat_ply("/nonexistent/x.ply", g, sh_degree=2.5),
        "camera width": lambda: Camera.from_opengl_c2w(np.eye(4), 10, 10, 5, 5, 3.7, 10),
        "raster width": lambda: rasterization(
            t(g.means),
            t(g.quats),
            t(np.exp(g.log_scales)),
            t(g.opacity_logits),
            t(g.sh[:, 0]),
            torch.eye(4)[None],
            torch.eye(3)[None],
            3.7,
            8,
        ),
        "raster sh degree": lambda: rasterization(
            t(g.means),
            t(g.quats),
            t(np.exp(g.log_scales)),
            t(g.opacity_logits),
            t(g.sh),
            torch.eye(4)[None],
            torch.eye(3)[None],
            8,
            8,
            sh_degree=0.5,
        ),
    }


@pytest.mark.parametrize(
    "call", ["knn k", "knn_mean_distance k", "sor neighbours", "downsample target", "sh degree",
             "export sh degree", "camera width", "raster width", "raster sh degree"],
)  # fmt: skip
def test_python_apis_refuse_non_integer_values(call):
    with pytest.raises(InputError, match="must be an integer"):
        _api_calls()[call]()
