"""Pinhole cameras in the rasterizer's convention, and conversions from the others.

World frame: z up (plants grow along +z), as in Blender and threestudio.
Camera frame: OpenCV (x right, y down, z forward); ``viewmat`` is world-to-camera, the
gsplat ``viewmats`` convention. NeRF/nerfstudio ``transform_matrix`` is camera-to-world in
OpenGL axes (x right, y up, z backward); ``Camera.from_opengl_c2w`` converts it.
Orbit angles: azimuth 0 looks from +x towards the target, positive azimuth turns towards +y;
elevation is the angle above the xy-plane.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from plantdreamer.errors import InputError
from plantdreamer.integers import as_int

# OpenGL camera axes -> OpenCV camera axes (flip y and z).
_GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True)
class Camera:
    """One pinhole camera. Matrices are float64 [4, 4] (world-to-camera) and [3, 3]."""

    viewmat: np.ndarray
    K: np.ndarray
    width: int
    height: int
    # Orbit parameters when the camera was made by `orbit` (view-dependent prompts use them).
    elevation_deg: float | None = None
    azimuth_deg: float | None = None
    distance: float | None = None

    def __post_init__(self) -> None:
        if self.viewmat.shape != (4, 4) or self.K.shape != (3, 3):
            raise InputError(
                f"camera needs a 4x4 viewmat and a 3x3 K, got {self.viewmat.shape}, {self.K.shape}"
            )
        if self.width <= 0 or self.height <= 0:
            raise InputError(f"image size must be positive, got {self.width}x{self.height}")
        if not (np.isfinite(self.viewmat).all() and np.isfinite(self.K).all()):
            raise InputError("camera matrices contain NaN or Inf")

    def check_renderable(self, what: str = "camera") -> None:
        """InputError unless the rasterizer takes this camera as it is given to it (float32):
        finite matrices and positive focal lengths. A focal length of 1e-300 is 0, and
        1e308 is infinite, in float32: refused here, before a command writes anything."""
        view32 = self.viewmat.astype(np.float32)
        k32 = self.K.astype(np.float32)
        if not (np.isfinite(view32).all() and np.isfinite(k32).all()):
            raise InputError(f"{what}: its pose or intrinsics overflow float32 (as rendered)")
        if not (k32[0, 0] > 0 and k32[1, 1] > 0):
            raise InputError(
                f"{what}: focal lengths fx={self.K[0, 0]:g}, fy={self.K[1, 1]:g} are not "
                "positive in float32 (as rendered)"
            )

    @property
    def c2w(self) -> np.ndarray:
        """Camera-to-world in OpenCV axes."""
        return np.linalg.inv(self.viewmat)

    @property
    def position(self) -> np.ndarray:
        return self.c2w[:3, 3]

    @property
    def fovy_deg(self) -> float:
        return math.degrees(2.0 * math.atan(self.height / (2.0 * self.K[1, 1])))

    def resized(self, width: int, height: int) -> Camera:
        """The same view at ``width`` x ``height`` pixels: the intrinsics scaled per axis
        (focal lengths and principal point; pixel centres stay at +0.5), the pose and the
        orbit parameters kept."""
        sx, sy = width / self.width, height / self.height
        K = self.K.copy()
        K[0, :] *= sx
        K[1, :] *= sy
        return replace(self, K=K, width=as_int("width", width), height=as_int("height", height))

    def to_opengl_c2w(self) -> np.ndarray:
        return self.c2w @ _GL_TO_CV

    @classmethod
    def from_opengl_c2w(
        cls, c2w: np.ndarray, fx: float, fy: float, cx: float, cy: float, width: int, height: int
    ) -> Camera:
        c2w = np.asarray(c2w, dtype=np.float64)
        if c2w.shape == (3, 4):
            c2w = np.vstack([c2w, [0.0, 0.0, 0.0, 1.0]])
        if c2w.shape != (4, 4):
            raise InputError(f"transform_matrix must be 4x4 or 3x4, got {list(c2w.shape)}")
        viewmat = np.linalg.inv(c2w @ _GL_TO_CV)
        return cls(
            viewmat, intrinsics(fx, fy, cx, cy), as_int("width", width), as_int("height", height)
        )

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (pixel centres at +0.5) and camera-space depth of world points."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        cam = pts @ self.viewmat[:3, :3].T + self.viewmat[:3, 3]
        z = cam[:, 2]
        uv = cam[:, :2] / z[:, None] * [self.K[0, 0], self.K[1, 1]] + [self.K[0, 2], self.K[1, 2]]
        return uv, z


def intrinsics(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def intrinsics_from_fovy(fovy_deg: float, width: int, height: int) -> np.ndarray:
    """Square pixels, principal point at the image centre."""
    if not 0.0 < fovy_deg < 180.0:
        raise InputError(f"fovy must be in (0, 180) degrees, got {fovy_deg}")
    f = 0.5 * height / math.tan(math.radians(fovy_deg) / 2.0)
    return intrinsics(f, f, width / 2.0, height / 2.0)


def look_at(
    eye: Sequence[float] | np.ndarray, target: Sequence[float] = (0.0, 0.0, 0.0)
) -> np.ndarray:
    """World-to-camera (OpenCV axes) for a camera at ``eye`` looking at ``target``, z up."""
    eye_v = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye_v
    norm = np.linalg.norm(forward)
    if norm == 0.0:
        raise InputError("camera position equals its target")
    forward /= norm
    up = np.array([0.0, 0.0, 1.0])
    if abs(forward @ up) > 1.0 - 1e-9:  # looking straight down or up: pick +y as 'up'
        up = np.array([0.0, 1.0, 0.0])
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    viewmat = np.eye(4)
    viewmat[:3, :3] = np.stack([right, down, forward])
    viewmat[:3, 3] = -viewmat[:3, :3] @ eye_v
    return viewmat


def orbit(
    distance: float,
    elevation_deg: float,
    azimuth_deg: float,
    fovy_deg: float,
    width: int,
    height: int,
    target: Sequence[float] = (0.0, 0.0, 0.0),
) -> Camera:
    """A camera on a sphere around ``target``, looking at it."""
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    offset = distance * np.array(
        [math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)]
    )
    eye = np.asarray(target, dtype=np.float64) + offset
    return Camera(
        look_at(eye, target),
        intrinsics_from_fovy(fovy_deg, width, height),
        width,
        height,
        elevation_deg=float(elevation_deg),
        azimuth_deg=float(azimuth_deg),
        distance=float(distance),
    )


def orbit_ring(
    n: int, distance: float, elevation_deg: float, fovy_deg: float, width: int, height: int
) -> list[Camera]:
    """``n`` cameras evenly spaced in azimuth (the evaluation orbit and turntables)."""
    return [
        orbit(distance, elevation_deg, -180.0 + 360.0 * i / n, fovy_deg, width, height)
        for i in range(n)
    ]


def stack(cameras: Sequence[Camera]) -> tuple[np.ndarray, np.ndarray]:
    """``viewmats`` [C, 4, 4] and ``Ks`` [C, 3, 3] (float32) for ``rasterization``."""
    if not cameras:
        raise InputError("no cameras given")
    sizes = {(c.width, c.height) for c in cameras}
    if len(sizes) != 1:
        raise InputError(f"cameras of one batch must share an image size, got {sorted(sizes)}")
    viewmats = np.stack([c.viewmat for c in cameras]).astype(np.float32)
    ks = np.stack([c.K for c in cameras]).astype(np.float32)
    return viewmats, ks
