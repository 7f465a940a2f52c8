"""3DGS PLY in the INRIA layout: bit-exact round trips, SH layout, padding, and readers'
tolerance of files without normals."""

from __future__ import annotations

import numpy as np
import pytest

from plantdreamer.errors import PlyError, PlyWarning
from plantdreamer.gaussians import Gaussians
from plantdreamer.io import read_ply_columns, read_splat_ply, write_splat_ply


def with_lossy_values(g: Gaussians) -> Gaussians:
    # Values a lossy path would change: NaN payloads, -0.0, subnormals, infinities.
    g.means[0] = [np.float32(-0.0), np.float32(1e-45), np.inf]
    g.sh.view(np.uint32)[1, 0, 0] = 0x7FC00123
    return g


def assert_bit_equal(a: Gaussians, b: Gaussians) -> None:
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype == np.float32 and x.shape == y.shape, name
        np.testing.assert_array_equal(x.view(np.uint32), y.view(np.uint32), err_msg=name)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_round_trip_is_bit_exact(tmp_path, degree, random_gaussians):
    g = with_lossy_values(random_gaussians(257, degree))
    write_splat_ply(tmp_path / "g.ply", g)
    back = read_splat_ply(tmp_path / "g.ply")
    assert back.sh_degree == degree
    assert_bit_equal(g, back)


def test_layout_is_inria(tmp_path, random_gaussians):
    g = with_lossy_values(random_gaussians(5, 1))
    write_splat_ply(tmp_path / "g.ply", g)
    cols = read_ply_columns(tmp_path / "g.ply")
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(9)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    assert list(cols) == names
    assert all(c.dtype == np.float32 for c in cols.values())
    # f_rest is channel-major: f_rest_{c * 3 + j} is SH coefficient j + 1 of channel c.
    for c in range(3):
        for j in range(3):
            np.testing.assert_array_equal(cols[f"f_rest_{c * 3 + j}"], g.sh[:, j + 1, c])
    np.testing.assert_array_equal(cols["rot_0"], g.quats[:, 0])  # w first
    np.testing.assert_array_equal(cols["nx"], 0)
    assert (tmp_path / "g.ply").read_bytes().startswith(b"ply\nformat binary_little_endian 1.0")


def test_padding_to_degree_3_for_strict_viewers(tmp_path, random_gaussians):
    g = with_lossy_values(random_gaussians(10, 0))
    write_splat_ply(tmp_path / "g.ply", g, sh_degree=3)
    cols = read_ply_columns(tmp_path / "g.ply")
    assert sum(n.startswith("f_rest_") for n in cols) == 45
    back = read_splat_ply(tmp_path / "g.ply")
    assert back.sh_degree == 3
    np.testing.assert_array_equal(back.sh[:, 0], g.sh[:, 0])
    assert not back.sh[:, 1:].any()


def test_reads_files_without_normals_written_by_plyfile(tmp_path, random_gaussians):
    plyfile = pytest.importorskip("plyfile")
    g = with_lossy_values(random_gaussians(20, 1, seed=3))
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(9)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    rest = g.sh[:, 1:].transpose(0, 2, 1).reshape(20, 9)
    values = np.concatenate(
        [g.means, g.sh[:, 0], rest, g.opacity_logits[:, None], g.log_scales, g.quats], axis=1
    )
    data = np.empty(20, dtype=[(n, "f4") for n in names])
    for i, n in enumerate(names):
        data[n] = values[:, i]
    plyfile.PlyData([plyfile.PlyElement.describe(data, "vertex")]).write(str(tmp_path / "gs.ply"))
    assert_bit_equal(read_splat_ply(tmp_path / "gs.ply"), g)


def test_bad_splat_files(tmp_path, random_gaussians):
    g = with_lossy_values(random_gaussians(3, 1))
    write_splat_ply(tmp_path / "g.ply", g)
    raw = (tmp_path / "g.ply").read_bytes()
    (tmp_path / "b.ply").write_bytes(raw.replace(b"property float f_rest_8\n", b""))
    # Dropping a property from the header leaves data after the declared rows: a warning
    # (the declared rows are read, as plyfile does), then a PlyError for the f_rest count;
    # a strict read stops at the extra data.
    with pytest.warns(PlyWarning, match="after the last element"), pytest.raises(PlyError):
        read_splat_ply(tmp_path / "b.ply")
    with pytest.raises(PlyError, match="after the last element"):
        read_splat_ply(tmp_path / "b.ply", strict=True)
    (tmp_path / "c.ply").write_bytes(raw.replace(b"f_rest_8", b"f_rest_9"))
    with pytest.raises(PlyError, match="numbered"):
        read_splat_ply(tmp_path / "c.ply")
    (tmp_path / "d.ply").write_bytes(raw.replace(b"opacity", b"opacitx"))
    with pytest.raises(PlyError, match="opacity"):
        read_splat_ply(tmp_path / "d.ply")
    from plantdreamer.cloud import PointCloud
    from plantdreamer.io import write_ply

    rng = np.random.default_rng(0)
    attrs = {n: rng.normal(size=4).astype(np.float32) for n in
             ["f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
              "rot_0", "rot_1", "rot_2", "rot_3", "f_rest_0", "f_rest_1"]}  # fmt: skip
    write_ply(tmp_path / "e.ply", PointCloud(np.zeros((4, 3), np.float32), attributes=attrs))
    with pytest.raises(PlyError, match="2 f_rest"):
        read_splat_ply(tmp_path / "e.ply")
