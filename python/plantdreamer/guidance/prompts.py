"""View-dependent text prompts: a species prompt plus a suffix naming the view.

The prompt comes from a template with a ``{species}`` field: the paper's "a {species} plant
in a pot" by default (LoRA training captions use the same template, so a LoRA is used with
the words it was trained on), or the authors' released "A photo of {species} plants". The
negative prompt (the unconditional branch of classifier-free guidance) defaults to the
authors' released one. The released code (threestudio) appends
a view word chosen from the camera angles, which helps SDS keep the back of an object from
growing a second front. Angles follow ``plantdreamer.cameras``: azimuth 0 looks from +x
towards the plant, positive azimuth turns towards +y, elevation is above the ground plane.

- ``overhead`` if elevation > 60 degrees (threestudio's threshold), otherwise by azimuth
  wrapped to (-180, 180]:
- ``front`` if |azimuth| < 45, ``back`` if |azimuth| > 135, ``side`` otherwise.

"Front" is arbitrary for a plant (no face); azimuth 0 is the camera that looks along -x.
"""

from __future__ import annotations

import math

import numpy as np

from plantdreamer.cameras import Camera
from plantdreamer.errors import InputError
from plantdreamer.guidance.config import DEFAULT_PROMPT_TEMPLATE

OVERHEAD_ELEVATION_DEG = 60.0
FRONT_HALF_ANGLE_DEG = 45.0
BACK_HALF_ANGLE_DEG = 45.0  # back = |azimuth| > 180 - this

VIEWS = ("front", "side", "back", "overhead")


def check_template(template: str) -> str:
    """The template itself, or InputError unless it has exactly the field ``{species}``."""
    try:
        template.format(species="x")
    except (KeyError, IndexError, ValueError) as exc:
        raise InputError(f"prompt template {template!r} is not valid: {exc}") from None
    if "{species}" not in template:
        raise InputError(f"prompt template must contain '{{species}}', got {template!r}")
    return template


def base_prompt(species: str, template: str = DEFAULT_PROMPT_TEMPLATE) -> str:
    """The prompt for a species from a ``{species}`` template."""
    species = species.strip()
    if not species:
        raise InputError("species name is empty")
    return check_template(template).format(species=species)


def wrap_azimuth(azimuth_deg: float) -> float:
    """Azimuth in (-180, 180]."""
    wrapped = math.fmod(azimuth_deg, 360.0)
    if wrapped <= -180.0:
        wrapped += 360.0
    elif wrapped > 180.0:
        wrapped -= 360.0
    return wrapped


def view_name(elevation_deg: float, azimuth_deg: float) -> str:
    """One of ``VIEWS`` for a camera at these orbit angles (degrees)."""
    if not (math.isfinite(elevation_deg) and math.isfinite(azimuth_deg)):
        raise InputError(f"camera angles must be finite, got {elevation_deg}, {azimuth_deg}")
    if elevation_deg > OVERHEAD_ELEVATION_DEG:
        return "overhead"
    az = abs(wrap_azimuth(azimuth_deg))
    if az < FRONT_HALF_ANGLE_DEG:
        return "front"
    if az > 180.0 - BACK_HALF_ANGLE_DEG:
        return "back"
    return "side"


def view_prompt(
    species: str,
    elevation_deg: float,
    azimuth_deg: float,
    template: str = DEFAULT_PROMPT_TEMPLATE,
) -> str:
    """ "a {species} plant in a pot, {front|side|back|overhead} view"."""
    return f"{base_prompt(species, template)}, {view_name(elevation_deg, azimuth_deg)} view"


def camera_angles(
    camera: Camera, target: tuple[float, float, float] = (0.0, 0.0, 0.0)
) -> tuple[float, float]:
    """(elevation, azimuth) in degrees: the orbit parameters if the camera has them, else
    computed from its position relative to ``target`` (the plant is centred at the origin)."""
    if camera.elevation_deg is not None and camera.azimuth_deg is not None:
        return camera.elevation_deg, camera.azimuth_deg
    offset = camera.position - np.asarray(target, dtype=np.float64)
    dist = float(np.linalg.norm(offset))
    if dist == 0.0:
        return 0.0, 0.0
    elevation = math.degrees(math.asin(max(-1.0, min(1.0, offset[2] / dist))))
    azimuth = math.degrees(math.atan2(offset[1], offset[0]))
    return elevation, azimuth


def camera_prompt(species: str, camera: Camera, template: str = DEFAULT_PROMPT_TEMPLATE) -> str:
    """The view-dependent prompt for one camera."""
    return view_prompt(species, *camera_angles(camera), template=template)
