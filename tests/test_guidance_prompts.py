"""View-dependent prompts from camera angles (azimuth 0 looks from +x)."""

import numpy as np
import pytest

from plantdreamer.cameras import Camera, look_at, orbit
from plantdreamer.errors import InputError
from plantdreamer.guidance.prompts import camera_angles, camera_prompt, view_name, view_prompt


@pytest.mark.parametrize(
    ("elevation", "azimuth", "view"),
    [
        (15, 0, "front"),
        (15, 44.9, "front"),
        (15, -44.9, "front"),
        (15, 45, "side"),
        (15, -90, "side"),
        (15, 135, "side"),
        (15, 135.1, "back"),
        (15, 180, "back"),
        (15, -180, "back"),
        (15, 360, "front"),
        (15, 405, "side"),
        (15, -225, "side"),
        (60, 0, "front"),
        (60.1, 180, "overhead"),
        (-10, 180, "back"),
    ],
)
def test_view_boundaries(elevation, azimuth, view):
    assert view_name(elevation, azimuth) == view


def test_prompt_text():
    assert view_prompt("bean", 15, 0) == "a bean plant in a pot, front view"
    assert view_prompt(" kale ", 80, 0) == "a kale plant in a pot, overhead view"


def test_bad_inputs():
    with pytest.raises(InputError):
        view_prompt("", 0, 0)
    with pytest.raises(InputError):
        view_name(float("nan"), 0)


@pytest.mark.parametrize(("elevation", "azimuth"), [(15, 0), (30, 100), (-5, -170), (75, 45)])
def test_angles_from_a_camera_without_orbit_parameters(elevation, azimuth):
    cam = orbit(4.0, elevation, azimuth, 60.0, 32, 32)
    bare = Camera(cam.viewmat, cam.K, 32, 32)  # e.g. read from a transforms.json
    el, az = camera_angles(bare)
    assert el == pytest.approx(elevation, abs=1e-9)
    assert az == pytest.approx(azimuth, abs=1e-9)
    assert camera_prompt("mint", bare) == camera_prompt("mint", cam)


def test_camera_looking_from_minus_x_is_the_back():
    cam = Camera(look_at([-5.0, 0.0, 1.0]), np.eye(3), 8, 8)
    assert camera_prompt("bean", cam).endswith("back view")
