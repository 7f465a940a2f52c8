"""Camera conventions: OpenCV world-to-camera, z-up orbits, OpenGL c2w round trips."""

import numpy as np
import pytest

from plantdreamer.cameras import Camera, intrinsics_from_fovy, look_at, orbit, orbit_ring, stack
from plantdreamer.errors import InputError


def test_orbit_target_projects_to_image_centre():
    cam = orbit(4.0, 15.0, 30.0, 70.0, 64, 48)
    uv, z = cam.project(np.zeros((1, 3)))
    np.testing.assert_allclose(uv[0], [32.0, 24.0], atol=1e-9)
    np.testing.assert_allclose(z[0], 4.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(cam.position), 4.0)


def test_azimuth_zero_looks_from_plus_x_and_up_is_up_in_the_image():
    cam = orbit(5.0, 0.0, 0.0, 60.0, 100, 100)
    np.testing.assert_allclose(cam.position, [5.0, 0.0, 0.0], atol=1e-9)
    # A point above the target appears above the centre (smaller row index, y down).
    uv, _ = cam.project(np.array([[0.0, 0.0, 1.0]]))
    assert uv[0, 1] < 50.0
    # Looking along -x with z up, the camera's right is +y (right-handed world).
    uv, _ = cam.project(np.array([[0.0, 1.0, 0.0]]))
    assert uv[0, 0] > 50.0


def test_fovy_round_trip():
    k = intrinsics_from_fovy(70.0, 200, 100)
    cam = Camera(np.eye(4), k, 200, 100)
    assert cam.fovy_deg == pytest.approx(70.0)


def test_opengl_c2w_round_trip_and_projection():
    cam = orbit(3.0, 40.0, -120.0, 50.0, 80, 60)
    gl = cam.to_opengl_c2w()
    # OpenGL cameras look along their -z axis: towards the target.
    forward = -gl[:3, 2]
    np.testing.assert_allclose(forward, -cam.position / np.linalg.norm(cam.position), atol=1e-9)
    back = Camera.from_opengl_c2w(gl, cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2], 80, 60)
    np.testing.assert_allclose(back.viewmat, cam.viewmat, atol=1e-9)
    p = np.array([[0.3, -0.2, 0.5]])
    np.testing.assert_allclose(back.project(p)[0], cam.project(p)[0], atol=1e-9)


def test_straight_down_view_is_well_defined():
    vm = look_at([0.0, 0.0, 5.0])
    assert np.isfinite(vm).all()
    np.testing.assert_allclose(vm[:3, :3] @ vm[:3, :3].T, np.eye(3), atol=1e-12)


def test_ring_and_stack():
    cams = orbit_ring(8, 4.0, 15.0, 70.0, 32, 32)
    viewmats, ks = stack(cams)
    assert viewmats.shape == (8, 4, 4) and ks.shape == (8, 3, 3)
    assert viewmats.dtype == np.float32
    azimuths = [c.azimuth_deg for c in cams]
    assert azimuths[0] == -180.0 and azimuths[-1] == pytest.approx(135.0)


def test_bad_cameras_are_rejected():
    with pytest.raises(InputError):
        look_at([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])
    with pytest.raises(InputError):
        intrinsics_from_fovy(0.0, 10, 10)
    with pytest.raises(InputError):
        stack([orbit(4, 0, 0, 60, 10, 10), orbit(4, 0, 0, 60, 20, 10)])
    with pytest.raises(InputError):
        Camera(np.full((4, 4), np.nan), np.eye(3), 10, 10)


def test_framed_distance_keeps_every_gaussian_inside_every_view_with_the_margin():
    """At the framed distance each Gaussian's 2-sigma sphere is inside every view's frustum
    shrunk by the margin (checked in camera space, through the cameras' own matrices), one
    of them touching it; a little closer, one sticks out. A non-square image too."""
    import math

    from plantdreamer.framing import (
        FRAME_AZIMUTHS,
        FRAME_MARGIN,
        FRAME_SIGMAS,
        framed_distance,
        orbit_distance,
    )
    from plantdreamer.gaussians import Gaussians

    rng = np.random.default_rng(5)
    n = 300
    means = (rng.normal(size=(n, 3)) * [1.5, 0.6, 0.9] + [0.3, 0.0, -0.2]).astype(np.float32)
    log_scales = np.log(rng.uniform(0.01, 0.1, (n, 3))).astype(np.float32)
    g = Gaussians(means, np.tile([1, 0, 0, 0], (n, 1)).astype(np.float32), log_scales,
                  np.full(n, 2.0, np.float32), np.zeros((n, 1, 3), np.float32))  # fmt: skip
    radius = FRAME_SIGMAS * np.exp(log_scales.astype(np.float64).max(axis=1))

    def worst(cameras):
        """Largest (|x| + r sqrt(1 + k^2)) / (k z) over Gaussians, sides and views (<= 1:
        inside)."""
        out = 0.0
        for cam in cameras:
            p = means.astype(np.float64) @ cam.viewmat[:3, :3].T + cam.viewmat[:3, 3]
            for axis, focal, size in ((0, cam.K[0, 0], cam.width), (1, cam.K[1, 1], cam.height)):
                k = size / (2 * focal) * (1 - FRAME_MARGIN)
                side = (np.abs(p[:, axis]) + radius * math.sqrt(1 + k * k)) / (k * p[:, 2])
                out = max(out, float(side.max()))
        return out

    for width, height, views in ((64, 64, 5), (96, 48, 80)):
        d = framed_distance(g, views, 20.0, 50.0, width, height)
        ring = orbit_ring(views, d, 20.0, 50.0, width, height)
        framed = ring  # an orbit of fewer views is framed at every 5 degrees too
        if views < FRAME_AZIMUTHS:
            framed = ring + orbit_ring(FRAME_AZIMUTHS, d, 20.0, 50.0, width, height)
        assert worst(ring) <= 1.0 and 0.999 < worst(framed) <= 1.0
        closer = [orbit(0.98 * d, 20.0, c.azimuth_deg, 50.0, width, height) for c in framed]
        assert worst(closer) > 1.0
        assert orbit_distance(g, framed) <= d  # any ring distance: the same directions
    # Faint Gaussians (below 1/255) and none at all.
    faint = Gaussians(means, g.quats, log_scales, np.full(n, -8.0, np.float32), g.sh)
    with pytest.raises(InputError, match="no visible Gaussian"):
        framed_distance(faint, 4, 15.0, 70.0, 32, 32)


def test_a_model_without_strays_is_framed_on_every_gaussian_and_strays_are_left_out():
    """Without strays the framed distance is every Gaussian's (as before strays were left
    out); two Gaussians far from the opacity mass do not set it."""
    import math

    from plantdreamer.framing import FRAME_AZIMUTHS, framed_distance, orbit_distance
    from plantdreamer.gaussians import Gaussians

    rng = np.random.default_rng(7)
    n = 2000
    means = (rng.normal(size=(n, 3)) * [1.0, 0.5, 2.0]).astype(np.float32)
    g = Gaussians(means, np.tile([1, 0, 0, 0], (n, 1)).astype(np.float32),
                  np.full((n, 3), -3.0, np.float32), np.full(n, 1.0, np.float32),
                  np.zeros((n, 1, 3), np.float32))  # fmt: skip
    ring = orbit_ring(FRAME_AZIMUTHS, 1.0, 20.0, 50.0, 64, 64)
    every = math.ceil(orbit_distance(g, ring) * 1e6) / 1e6
    assert framed_distance(g, 4, 20.0, 50.0, 64, 64) == every
    far = means.copy()
    far[:2] = [[500.0, 0.0, 0.0], [0.0, -500.0, 500.0]]
    strays = g.moved(far, 0.0)
    assert orbit_distance(strays, ring) > 50 * every  # every Gaussian: the strays set it
    assert framed_distance(strays, 4, 20.0, 50.0, 64, 64) <= every


def test_a_resized_camera_sees_the_same_view_at_the_new_size():
    cam = orbit(4.0, 20.0, 30.0, 55.0, 768, 768)
    small = cam.resized(512, 256)
    assert (small.width, small.height) == (512, 256)
    assert np.array_equal(small.viewmat, cam.viewmat) and small.distance == cam.distance
    points = np.random.default_rng(0).normal(scale=0.3, size=(50, 3))
    uv, z = cam.project(points)
    uv_small, z_small = small.project(points)
    np.testing.assert_allclose(uv_small, uv * [512 / 768, 256 / 768], rtol=1e-12)
    np.testing.assert_array_equal(z_small, z)
    assert small.fovy_deg == pytest.approx(cam.fovy_deg)
    with pytest.raises(InputError):
        cam.resized(0, 512)
