"""Camera rigs of the exported views: the evaluation orbit of before (the default), the rigs
phenotyping uses (turntable, side, top-down) and a random rig, each a distribution of
elevation, azimuth, distance, roll and field of view drawn from the plant's seed.

A rig other than the orbit draws, per view, an elevation, an azimuth, a distance and a roll
uniformly in its ranges (degrees; elevation 90 looks straight down), and a vertical field of
view (``eval-fovy-deg`` unless the rig gives a range). Distances are multiples of the framed
distance (``framing.orbit_distance``: the closest at which every Gaussian of the plant, less
its strays, is in the view with ``FRAME_MARGIN`` to spare): 1 frames the whole plant, 1.5
shows it smaller. An ``even`` rig (a turntable) spaces its azimuths evenly and frames all its
views at one distance, as a camera that stays put while the plant turns; the others frame
each view on its own. A range given as a setting replaces the rig's own.

Cameras are built from the angles directly (right = the horizontal direction of increasing
azimuth, turned by the roll about the optical axis), so a view straight down is as well
defined as any other: no up-vector is involved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from plantdreamer.cameras import Camera, intrinsics_from_fovy
from plantdreamer.errors import InputError
from plantdreamer.framing import orbit_distance, without_strays
from plantdreamer.gaussians import Gaussians
from plantdreamer.settings import setting

ORBIT, TRANSFORMS = "orbit", "transforms"
RIG_NAMES = (ORBIT, "turntable", "side", "top-down", "random", TRANSFORMS)
RIG_STREAM = 0x72696773  # "rigs": the cameras' random stream, apart from training's
Range = tuple[float, float]


@dataclass(frozen=True)
class RigDistribution:
    """A rig: ranges (low, high) drawn uniformly per view; ``fovy_deg`` None is the fixed
    ``eval-fovy-deg``; ``even``: azimuths evenly spaced over their range and one distance."""

    elevation_deg: Range
    azimuth_deg: Range
    distance: Range
    roll_deg: Range
    fovy_deg: Range | None = None
    even: bool = False


# The rigs by name (docs/datasets.md). Overhead rigs look straight down on rosettes and
# trays (the CVPPP sets); conveyor and side rigs look level at the plant; a turntable turns
# the plant before a fixed camera; the random rig varies everything.
RIGS: dict[str, RigDistribution] = {
    "turntable": RigDistribution((0.0, 0.0), (-180.0, 180.0), (1.0, 1.0), (0.0, 0.0), even=True),
    "side": RigDistribution((0.0, 10.0), (-180.0, 180.0), (1.0, 1.3), (0.0, 0.0)),
    "top-down": RigDistribution((90.0, 90.0), (-180.0, 180.0), (1.0, 1.4), (0.0, 0.0)),
    "random": RigDistribution(
        (0.0, 90.0), (-180.0, 180.0), (1.0, 1.6), (-15.0, 15.0), fovy_deg=(30.0, 70.0)
    ),
}
MAX_DISTANCE = 100.0  # framed distances: beyond this the plant is a speck
MAX_SIDE = 8192  # an image side (as --resolution's)


@dataclass
class RigConfig:
    """The rig section: which rig the exported views come from, and its ranges."""

    rig: str = setting(
        ORBIT,
        "Cameras of the exported views: orbit (the evaluation orbit: eval-views at "
        "eval-elevation-deg), turntable, side, top-down, random (ranges drawn per view from "
        "the seed), or transforms (the cameras of rig-transforms, framed on the plant).",
        choices=RIG_NAMES,
    )
    rig_elevation_deg: tuple[float, float] | None = setting(
        None, "Elevation range LOW HIGH of the rig's views (degrees; 90: straight down).",
        default_text="the rig's",
    )  # fmt: skip
    rig_azimuth_deg: tuple[float, float] | None = setting(
        None, "Azimuth range LOW HIGH of the rig's views (degrees).", default_text="the rig's"
    )
    rig_distance: tuple[float, float] | None = setting(
        None,
        "Distance range LOW HIGH of the rig's views, in framed distances (1: the closest at "
        "which the whole plant is in view).",
        default_text="the rig's",
    )
    rig_roll_deg: tuple[float, float] | None = setting(
        None, "Roll range LOW HIGH of the rig's views about their optical axis (degrees).",
        default_text="the rig's",
    )  # fmt: skip
    rig_fovy_deg: tuple[float, float] | None = setting(
        None, "Vertical field of view range LOW HIGH of the rig's views (degrees).",
        default_text="eval-fovy-deg, or the rig's",
    )  # fmt: skip
    rig_width: int | None = setting(
        None, "Image width of the rig's views (pixels).", default_text="resolution"
    )
    rig_height: int | None = setting(
        None, "Image height of the rig's views (pixels).", default_text="resolution"
    )
    rig_transforms: str | None = setting(
        None,
        "A real rig's transforms.json (nerfstudio layout) for --rig transforms: its cameras, "
        "intrinsics kept, placed on each plant and scaled so the whole plant is in view.",
    )

    def __post_init__(self) -> None:
        for f in fields(self):  # ranges read from JSON or TOML come as lists
            value = getattr(self, f.name)
            if isinstance(value, list):
                setattr(self, f.name, tuple(value))

    def ranges(self) -> dict[str, Range | None]:
        return {
            "elevation_deg": self.rig_elevation_deg,
            "azimuth_deg": self.rig_azimuth_deg,
            "distance": self.rig_distance,
            "roll_deg": self.rig_roll_deg,
            "fovy_deg": self.rig_fovy_deg,
        }

    def validate(self) -> None:
        """Ranges only where a rig draws them; each (low, high) with low <= high and every
        value in it a camera; the transforms rig with its file and the file only with it."""
        given = [k for k, v in self.ranges().items() if v is not None]
        given += [k for k in ("width", "height") if getattr(self, f"rig_{k}") is not None]
        if self.rig in (ORBIT, TRANSFORMS) and given:
            names = ", ".join("rig-" + k.replace("_", "-") for k in given)
            raise InputError(f"{names} apply to the drawn rigs, not --rig {self.rig}")
        if (self.rig == TRANSFORMS) != (self.rig_transforms is not None):
            raise InputError("--rig transforms and --rig-transforms FILE go together")
        for side in ("width", "height"):
            value = getattr(self, f"rig_{side}")
            if value is not None and not 8 <= value <= MAX_SIDE:
                raise InputError(f"rig-{side} must be in 8..{MAX_SIDE}, got {value}")
        if self.rig in RIGS:
            self.distribution()  # checks the ranges

    def distribution(self) -> RigDistribution:
        """The rig's distribution with the ranges given here in place of its own."""
        if self.rig not in RIGS:
            raise InputError(f"--rig {self.rig} draws no cameras")
        own = RIGS[self.rig]
        given = {k: v for k, v in self.ranges().items() if v is not None}
        for name, (low, high) in given.items():
            _check_range(name, low, high)
        values = {f.name: given.get(f.name, getattr(own, f.name)) for f in fields(own)}
        return RigDistribution(**values)


def _check_range(name: str, low: float, high: float) -> None:
    option = "rig-" + name.replace("_", "-")
    if not (math.isfinite(low) and math.isfinite(high) and low <= high):
        raise InputError(f"{option} is a range LOW HIGH; got {low:g} {high:g}")
    limits = {
        "elevation_deg": (-90.0, 90.0, "degrees"),
        "azimuth_deg": (-360.0, 360.0, "degrees"),
        "roll_deg": (-180.0, 180.0, "degrees"),
    }
    if name in limits:
        lo, hi, unit = limits[name]
        if not lo <= low <= high <= hi:
            raise InputError(f"{option} must lie in [{lo:g}, {hi:g}] {unit}, got {low:g} {high:g}")
    elif name == "distance" and not 0 < low <= high <= MAX_DISTANCE:
        raise InputError(f"{option} must lie in (0, {MAX_DISTANCE:g}], got {low:g} {high:g}")
    elif name == "fovy_deg" and not 0 < low <= high < 180:
        raise InputError(f"{option} must lie in (0, 180) degrees, got {low:g} {high:g}")


def rig_camera(
    distance: float,
    elevation_deg: float,
    azimuth_deg: float,
    roll_deg: float,
    fovy_deg: float,
    width: int,
    height: int,
) -> Camera:
    """A camera ``distance`` from the origin at these angles, looking at it, turned by
    ``roll_deg`` about its optical axis (positive turns its x axis towards its y axis)."""
    el, az, roll = (math.radians(a) for a in (elevation_deg, azimuth_deg, roll_deg))
    toward = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    forward = -toward
    right = np.array([-math.sin(az), math.cos(az), 0.0])  # never parallel to forward
    down = np.cross(forward, right)
    c, s = math.cos(roll), math.sin(roll)
    right, down = c * right + s * down, c * down - s * right
    viewmat = np.eye(4)
    viewmat[:3, :3] = np.stack([right, down, forward])
    viewmat[:3, 3] = -viewmat[:3, :3] @ (distance * toward)
    return Camera(
        viewmat,
        intrinsics_from_fovy(fovy_deg, width, height),
        width,
        height,
        elevation_deg=float(elevation_deg),
        azimuth_deg=float(azimuth_deg),
        distance=float(distance),
    )


@dataclass(frozen=True)
class RigViews:
    """A rig's cameras and, per view, what was drawn (written beside the view)."""

    cameras: list[Camera]
    records: list[dict[str, Any]]


def draw_rig(
    rig: RigDistribution,
    scene: Gaussians,
    views: int,
    seed: int,
    fovy_deg: float,
    width: int,
    height: int,
) -> RigViews:
    """``views`` cameras of ``rig`` around the origin of ``scene`` (its frame), drawn from
    ``seed``: the same arguments give the same cameras."""
    if views <= 0:
        return RigViews([], [])
    rng = np.random.default_rng([seed, RIG_STREAM])
    elevation = rng.uniform(*rig.elevation_deg, views)
    if rig.even:
        low, high = rig.azimuth_deg
        azimuth = low + (high - low) * np.arange(views) / views
    else:
        azimuth = rng.uniform(*rig.azimuth_deg, views)
    scale = rng.uniform(*rig.distance, views)
    roll = rng.uniform(*rig.roll_deg, views)
    fovy = rng.uniform(*rig.fovy_deg, views) if rig.fovy_deg else np.full(views, fovy_deg)
    unit = [
        rig_camera(1.0, e, a, r, f, width, height)
        for e, a, r, f in zip(elevation, azimuth, roll, fovy, strict=True)
    ]
    body = without_strays(scene)
    framed = [orbit_distance(body, [c]) for c in unit]
    if rig.even:
        framed = [max(framed)] * views
    cameras, records = [], []
    for i in range(views):
        distance = framed[i] * float(scale[i])
        angles = (float(elevation[i]), float(azimuth[i]), float(roll[i]), float(fovy[i]))
        cameras.append(rig_camera(distance, *angles, width, height))
        records.append(
            {
                "elevation_deg": angles[0],
                "azimuth_deg": angles[1],
                "roll_deg": angles[2],
                "fovy_deg": angles[3],
                "framed_distances": float(scale[i]),
            }
        )
    return RigViews(cameras, records)
