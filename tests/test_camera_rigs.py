"""Camera rigs of the exported views (camera_rigs.py, views/real_rig.py): each rig's views lie
in its ranges, straight-down views are proper cameras, the draws follow the seed, and a real
rig's transforms.json keeps its intrinsics and frames the plant as the orbit is framed."""

import json
import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from plantdreamer.camera_rigs import RIGS, RigConfig, draw_rig, rig_camera
from plantdreamer.cameras import look_at, orbit_ring
from plantdreamer.errors import InputError
from plantdreamer.framing import FRAME_MARGIN, orbit_distance, without_strays
from plantdreamer.gaussians import Gaussians, rgb_to_sh_dc
from plantdreamer.views.real_rig import framed_rig, rig_cameras, rig_centre


def cluster(n=400, seed=0, spread=(0.6, 0.4, 1.0)):
    rng = np.random.default_rng(seed)
    means = (rng.normal(size=(n, 3)) * spread).astype(np.float32)
    return Gaussians(
        means,
        np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
        np.full((n, 3), -4.0, np.float32),
        np.full(n, 3.0, np.float32),
        np.zeros((n, 1, 3), np.float32),
    )


def angles_of(camera):
    """Elevation and azimuth of a camera's position seen from the origin, its distance,
    and its vertical field of view (from its intrinsics)."""
    x, y, z = camera.position
    d = math.sqrt(x * x + y * y + z * z)
    elevation = math.degrees(math.asin(min(1.0, z / d)))
    return elevation, math.degrees(math.atan2(y, x)), d, camera.fovy_deg


@pytest.mark.parametrize("name", sorted(RIGS))
def test_every_rigs_views_lie_in_its_ranges_and_see_the_whole_plant(name):
    rig, g = RIGS[name], cluster()
    views = draw_rig(rig, g, 24, seed=5, fovy_deg=50.0, width=64, height=48)
    assert len(views.cameras) == 24
    body = without_strays(g)
    framed = [orbit_distance(body, [rig_camera(1.0, *_angles(r), 64, 48)]) for r in views.records]
    if rig.even:  # one distance: the farthest any view needs
        framed = [max(framed)] * len(framed)
    for cam, record, unit in zip(views.cameras, views.records, framed, strict=True):
        elevation, azimuth, distance, fovy = angles_of(cam)
        low, high = rig.elevation_deg
        assert low - 1e-6 <= elevation <= high + 1e-6
        if elevation < 89.999:  # straight down, the azimuth is the image's turn only
            assert math.isclose(math.cos(math.radians(azimuth - record["azimuth_deg"])), 1.0)
        lo_f, hi_f = rig.fovy_deg or (50.0, 50.0)
        assert lo_f - 1e-9 <= fovy <= hi_f + 1e-9
        assert cam.width == 64 and cam.height == 48
        # The distance is the drawn multiple of this view's framed distance.
        scale = distance / unit
        assert rig.distance[0] - 1e-9 <= scale <= rig.distance[1] + 1e-9
        assert scale == pytest.approx(record["framed_distances"])
        # At 1 framed distance or more, every Gaussian centre of the plant is in the view.
        uv, z = cam.project(body.means)
        assert (z > 0).all()
        assert (uv >= 0).all() and (uv[:, 0] <= 64).all() and (uv[:, 1] <= 48).all()
        # The optical axis goes through the plant's centre: it lands mid-image.
        np.testing.assert_allclose(cam.project(np.zeros((1, 3)))[0][0], [32, 24], atol=1e-9)


def _angles(record):
    return (record[k] for k in ("elevation_deg", "azimuth_deg", "roll_deg", "fovy_deg"))


def test_a_turntable_keeps_one_distance_and_even_azimuths():
    views = draw_rig(RIGS["turntable"], cluster(), 8, seed=1, fovy_deg=60.0, width=32, height=32)
    distances = {round(angles_of(c)[2], 12) for c in views.cameras}
    assert len(distances) == 1
    azimuths = [r["azimuth_deg"] for r in views.records]
    np.testing.assert_allclose(np.diff(azimuths), 45.0)


def test_straight_down_views_are_proper_cameras_at_any_azimuth_and_roll():
    for azimuth in (-180.0, -37.0, 0.0, 90.0, 151.0):
        for roll in (0.0, 20.0, -90.0):
            cam = rig_camera(3.0, 90.0, azimuth, roll, 60.0, 40, 30)
            rotation = cam.viewmat[:3, :3]
            np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
            assert np.linalg.det(rotation) == pytest.approx(1.0)
            np.testing.assert_allclose(rotation[2], [0, 0, -1], atol=1e-12)  # looks down
            np.testing.assert_allclose(cam.position, [0, 0, 3], atol=1e-12)
            # The azimuth and the roll turn the picture: image right is the horizontal
            # direction of increasing azimuth, turned by the roll.
            turn = math.radians(azimuth - roll)
            np.testing.assert_allclose(
                rotation[0], [-math.sin(turn), math.cos(turn), 0], atol=1e-12
            )


def test_rig_cameras_match_look_at_orbits_where_those_are_defined():
    for cam, ring in zip(
        [rig_camera(4.0, 15.0, a, 0.0, 70.0, 32, 32) for a in (-180.0, -90.0, 0.0, 90.0)],
        orbit_ring(4, 4.0, 15.0, 70.0, 32, 32),
        strict=True,
    ):
        np.testing.assert_allclose(cam.viewmat, ring.viewmat, atol=1e-12)


def test_a_rolled_view_turns_the_picture_about_its_centre():
    flat = rig_camera(4.0, 30.0, 10.0, 0.0, 60.0, 64, 64)
    rolled = rig_camera(4.0, 30.0, 10.0, 90.0, 60.0, 64, 64)
    p = np.array([[0.3, -0.2, 0.4]])
    (u0, v0), (u1, v1) = flat.project(p)[0][0] - 32, rolled.project(p)[0][0] - 32
    np.testing.assert_allclose([u1, v1], [v0, -u0], atol=1e-9)  # a quarter turn


def test_the_same_seed_draws_the_same_cameras_and_another_seed_others():
    g, rig = cluster(), RIGS["random"]
    a = draw_rig(rig, g, 6, seed=3, fovy_deg=50.0, width=32, height=32)
    b = draw_rig(rig, g, 6, seed=3, fovy_deg=50.0, width=32, height=32)
    c = draw_rig(rig, g, 6, seed=4, fovy_deg=50.0, width=32, height=32)
    for x, y in zip(a.cameras, b.cameras, strict=True):
        assert np.array_equal(x.viewmat, y.viewmat) and np.array_equal(x.K, y.K)
    assert a.records == b.records != c.records


def test_given_ranges_replace_the_rigs_own_and_bad_ones_are_refused():
    rig = RigConfig(rig="top-down", rig_distance=(2.0, 2.5), rig_fovy_deg=[20.0, 30.0])
    dist = rig.distribution()
    assert dist.distance == (2.0, 2.5) and dist.fovy_deg == (20.0, 30.0)
    assert dist.elevation_deg == RIGS["top-down"].elevation_deg
    bad = [
        RigConfig(rig="side", rig_elevation_deg=(10.0, 0.0)),
        RigConfig(rig="side", rig_elevation_deg=(0.0, 95.0)),
        RigConfig(rig="side", rig_distance=(0.0, 1.0)),
        RigConfig(rig="side", rig_fovy_deg=(10.0, 180.0)),
        RigConfig(rig="orbit", rig_distance=(1.0, 2.0)),  # the orbit draws nothing
        RigConfig(rig="orbit", rig_width=64),
        RigConfig(rig="transforms"),  # no file
        RigConfig(rig="side", rig_transforms="rig.json"),
        RigConfig(rig="random", rig_width=4),
    ]
    for config in bad:
        with pytest.raises(InputError):
            config.validate()


def write_rig(path, cameras, **shared):
    frames = [
        {"file_path": f"images/{i}.png", "transform_matrix": c.to_opengl_c2w().tolist()}
        for i, c in enumerate(cameras)
    ]
    path.write_text(json.dumps({**shared, "frames": frames}))
    return path


def test_a_real_rig_of_an_orbit_is_framed_at_the_orbits_distance(tmp_path):
    g = cluster()
    ring = orbit_ring(12, 7.0, 20.0, 50.0, 40, 40)
    k = ring[0].K
    path = write_rig(tmp_path / "transforms.json", ring, fl_x=k[0, 0], fl_y=k[1, 1],
                     cx=k[0, 2], cy=k[1, 2], w=40, h=40)  # fmt: skip
    framed = framed_rig(path, g)
    want = orbit_distance(without_strays(g), orbit_ring(12, 1.0, 20.0, 50.0, 40, 40))
    for cam, source in zip(framed, ring, strict=True):
        assert np.linalg.norm(cam.position) == pytest.approx(want, rel=1e-9)
        np.testing.assert_allclose(cam.viewmat[:3, :3], source.viewmat[:3, :3], atol=1e-12)


def test_a_real_rig_renders_with_its_own_intrinsics(tmp_path):
    """A rig of off-centre, non-square cameras around a point away from its file's origin:
    the framed cameras keep the file's intrinsics, and a bright Gaussian of a known scene
    lands on the pixel its projection names."""
    from plantdreamer.rasterizer import rasterization

    centre = np.array([5.0, -2.0, 1.0])
    sources = [rig_camera(2.0, e, a, r, 40.0, 90, 60) for e, a, r in
               ((10, 0, 0), (40, 100, 15), (70, -120, -10), (90, 30, 0))]  # fmt: skip
    for cam in sources:  # moved onto the rig's centre
        cam.viewmat[:3, 3] -= cam.viewmat[:3, :3] @ centre
    path = write_rig(tmp_path / "rig.json", sources, fl_x=70.0, fl_y=77.0, cx=40.0, cy=33.0,
                     w=90, h=60)  # fmt: skip
    np.testing.assert_allclose(rig_centre(rig_cameras(path)), centre, atol=1e-9)
    g = cluster(n=200, seed=2)
    bright = np.array([0.25, -0.15, 0.3], np.float32)
    means = np.vstack([g.means, bright])
    sh = np.vstack([np.full((200, 1, 3), rgb_to_sh_dc(np.float32([0.0, 0.0, 0.0]))),
                    rgb_to_sh_dc(np.float32([[[1.0, 1.0, 1.0]]]))])  # fmt: skip
    scene = Gaussians(
        means,
        np.tile(np.float32([1, 0, 0, 0]), (201, 1)),
        np.vstack([g.log_scales, np.full((1, 3), -5.0, np.float32)]),
        np.r_[np.full(200, -6.0, np.float32), np.float32(6.0)],  # faint body, opaque dot
        sh.astype(np.float32),
    )
    cameras = framed_rig(path, scene)
    for cam in cameras:
        np.testing.assert_allclose(cam.K, [[70.0, 0, 40.0], [0, 77.0, 33.0], [0, 0, 1]])
        assert (cam.width, cam.height) == (90, 60)
        image, _, _ = rasterization(
            torch.from_numpy(scene.means), torch.from_numpy(scene.quats),
            torch.from_numpy(np.exp(scene.log_scales)),
            torch.sigmoid(torch.from_numpy(scene.opacity_logits)),
            torch.from_numpy(scene.sh), torch.from_numpy(cam.viewmat[None].astype(np.float32)),
            torch.from_numpy(cam.K[None].astype(np.float32)), 90, 60, sh_degree=0,
        )  # fmt: skip
        brightness = image[0].sum(-1).numpy()
        row, col = np.unravel_index(np.argmax(brightness), brightness.shape)
        u, v = cam.project(bright[None])[0][0]
        assert abs(col + 0.5 - u) <= 1.0 and abs(row + 0.5 - v) <= 1.0


def test_a_rig_that_looks_away_from_its_centre_is_refused(tmp_path):
    toward = rig_camera(3.0, 10.0, 90.0, 0.0, 40.0, 32, 32)
    eye = np.array([3.0, 0.0, 0.5])
    away = replace(toward, viewmat=look_at(eye, 2 * eye))  # its back to the centre
    path = write_rig(tmp_path / "rig.json", [toward, away], fl_x=30.0, fl_y=30.0, cx=16.0,
                     cy=16.0, w=32, h=32)  # fmt: skip
    with pytest.raises(InputError, match="camera 1 does not look towards"):
        framed_rig(path, cluster())


def test_a_rig_of_parallel_cameras_is_framed_tightly(tmp_path):
    """Three overhead cameras side by side, unevenly (axes that miss the plant's centre): at
    the framed scale every Gaussian of the plant, with its 2-sigma extent, is in every view,
    and at a slightly smaller scale one is not."""
    cameras = []
    for x in (-0.5, 0.2, 0.6):
        cam = rig_camera(2.0, 90.0, 0.0, 0.0, 50.0, 48, 40)
        cameras.append(replace(cam, viewmat=look_at([x, 0.0, 2.0], [x, 0.0, 0.0])))
    path = write_rig(tmp_path / "rig.json", cameras, fl_x=40.0, fl_y=44.0, cx=20.0, cy=22.0,
                     w=48, h=40)  # fmt: skip
    g = cluster(seed=4)
    framed = framed_rig(path, g)
    body = without_strays(g)
    radius = 2.0 * np.exp(body.log_scales.max(axis=1))

    def inside(cams, shrink):
        """Every 2-sigma sphere inside the four side planes of each view, FRAME_MARGIN of
        the half-extent from the border (in camera coordinates, after the move)."""
        ok = True
        for cam in cams:
            viewmat = cam.viewmat.copy()
            viewmat[:3, 3] *= shrink  # the rig scaled about the centre (the origin)
            q = body.means @ viewmat[:3, :3].T + viewmat[:3, 3]
            fx, fy, cx, cy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]
            for axis, sign, extent in ((0, 1, (48 - cx) / fx), (0, -1, cx / fx),
                                       (1, 1, (40 - cy) / fy), (1, -1, cy / fy)):  # fmt: skip
                k = extent * (1 - FRAME_MARGIN)
                ok &= bool((sign * q[:, axis] + radius * math.sqrt(1 + k * k)
                            <= k * q[:, 2] + 1e-6).all())  # fmt: skip
        return ok

    assert inside(framed, 1.0)
    assert not inside(framed, 0.999)
