"""PointCloud and Gaussians validate their shapes and convert colours exactly."""

import numpy as np
import pytest

from plantdreamer.cloud import PointCloud
from plantdreamer.errors import InputError
from plantdreamer.gaussians import Gaussians, rgb_to_sh_dc, sh_dc_to_rgb


def make_gaussians(n=5, k=1):
    rng = np.random.default_rng(0)
    f = np.float32
    return Gaussians(
        rng.normal(size=(n, 3)).astype(f),
        rng.normal(size=(n, 4)).astype(f),
        rng.normal(size=(n, 3)).astype(f),
        rng.normal(size=n).astype(f),
        rng.normal(size=(n, k, 3)).astype(f),
    )


def test_point_cloud_subset_keeps_every_field():
    pc = PointCloud(
        np.arange(12, dtype=np.float32).reshape(4, 3),
        colors=np.zeros((4, 3), np.float32),
        attributes={"label": np.array([0, 1, 2, 3])},
    )
    sub = pc.subset(np.array([1, 3]))
    assert len(sub) == 2
    np.testing.assert_array_equal(sub.attributes["label"], [1, 3])
    assert sub.normals is None


@pytest.mark.parametrize(
    "kwargs",
    [
        {"positions": np.zeros((4, 2))},
        {"positions": np.zeros((4, 3)), "colors": np.zeros((3, 3))},
        {"positions": np.zeros((4, 3)), "attributes": {"label": np.zeros(5)}},
    ],
)
def test_point_cloud_rejects_inconsistent_shapes(kwargs):
    with pytest.raises(InputError):
        PointCloud(**kwargs)


def test_gaussians_sh_degree_padding_and_truncation():
    g = make_gaussians(k=1)
    assert g.sh_degree == 0
    g3 = g.with_sh_degree(3)
    assert g3.sh.shape == (5, 16, 3) and g3.sh_degree == 3
    np.testing.assert_array_equal(g3.sh[:, 0], g.sh[:, 0])
    assert not g3.sh[:, 1:].any()
    np.testing.assert_array_equal(g3.with_sh_degree(0).sh, g.sh)


def test_gaussians_reject_bad_shapes():
    g = make_gaussians()
    with pytest.raises(InputError, match="quats"):
        Gaussians(g.means, g.quats[:, :3], g.log_scales, g.opacity_logits, g.sh)
    with pytest.raises(InputError, match="sh"):
        Gaussians(g.means, g.quats, g.log_scales, g.opacity_logits, np.zeros((5, 2, 3)))


def test_colour_conversion_round_trip():
    rgb = np.array([[0.0, 0.5, 1.0]], dtype=np.float32)
    np.testing.assert_allclose(sh_dc_to_rgb(rgb_to_sh_dc(rgb)), rgb, atol=1e-6)
    np.testing.assert_allclose(sh_dc_to_rgb(np.zeros(3)), 0.5)
