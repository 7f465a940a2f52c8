"""Organ surfaces: parametric leaf blades, and the pot and soil every plant stands in.

A leaf blade is a surface over (u, v): u in [0, 1] runs along the midrib from the base to the
tip, v in [-1, 1] across the blade from the right to the left margin. Its half-width is the
species outline ``w(u)``; the midrib is a curve that curls in the leaf plane and droops under
gravity; the blade is folded up about the midrib (a V), cupped, and its margin may ruffle
(kale). The blade's upper (adaxial) side faces the turtle's U at insertion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plantdreamer.errors import InputError
from plantdreamer.lsystem.geometry import revolve, rotate_batch, tipped_grid_faces

GRAVITY = np.array([0.0, 0.0, -1.0])


@dataclass(frozen=True)
class LeafShape:
    """Species-specific leaf blade. Lengths are relative to the blade length unless noted.

    aspect: maximum width / length.  widest: u of the widest point.
    roundness: exponent of the outline; < 1 gives round shoulders, > 1 a narrow wedge.
    tip_taper: > 0 pulls the last part of the blade into an acuminate (drawn-out) tip.
    teeth, tooth_depth: serrated margin (teeth per side, depth as a fraction of the width).
    lobes, lobe_depth: rounded lobes along the margin (count per side, relative depth).
    fold: height of the margin above the midrib per unit of half-width (V fold).
    cup: extra height of the margins, quadratic across the blade.
    curl: radians the midrib turns over the whole blade (+ tip up, - tip down).
    droop: radians of gravity bending over the blade for a horizontal midrib.
    ruffle, ruffle_waves: margin wave amplitude (fraction of length) and waves along u.
    color, color_jitter, midrib_color: linear RGB in [0, 1]; jitter is relative per leaf.
    rows, cols: resolution along u (incl. the two tips) and across v (odd: one on the midrib).
    """

    aspect: float = 0.6
    widest: float = 0.4
    roundness: float = 0.8
    tip_taper: float = 0.0
    teeth: int = 0
    tooth_depth: float = 0.0
    lobes: float = 0.0
    lobe_depth: float = 0.0
    fold: float = 0.15
    cup: float = 0.0
    curl: float = 0.0
    droop: float = 0.5
    ruffle: float = 0.0
    ruffle_waves: float = 0.0
    color: tuple[float, float, float] = (0.22, 0.45, 0.12)
    color_jitter: float = 0.08
    midrib_color: tuple[float, float, float] = (0.45, 0.62, 0.30)
    rows: int = 18
    cols: int = 9

    def __post_init__(self) -> None:
        problems = []
        if not self.aspect > 0:
            problems.append("aspect must be > 0")
        if not 0 < self.widest < 1:
            problems.append("widest must be in (0, 1)")
        if not (0 <= self.tooth_depth < 1 and 0 <= self.lobe_depth < 1):
            problems.append("tooth_depth and lobe_depth must be in [0, 1)")
        if not 0 <= self.tip_taper < 1:
            problems.append("tip_taper must be in [0, 1)")
        if self.rows < 3 or self.cols < 3 or self.cols % 2 == 0:
            problems.append("rows must be >= 3 and cols odd and >= 3")
        if problems:
            raise InputError("LeafShape: " + "; ".join(problems))

    def half_width(self, u: np.ndarray) -> np.ndarray:
        """Outline half-width over u (relative to the blade length), 0 at both tips."""
        p = np.log(0.5) / np.log(self.widest)
        w = np.sin(np.pi * np.clip(u, 0.0, 1.0) ** p) ** self.roundness
        if self.tip_taper:
            w = w * (1.0 - self.tip_taper * np.clip((u - 0.6) / 0.4, 0.0, 1.0) ** 1.5)
        if self.teeth:
            saw = (u * self.teeth) % 1.0  # rises along each tooth, drops at its point
            w = w * (1.0 - self.tooth_depth * (1.0 - saw) * np.sin(np.pi * u))
        if self.lobes:
            w = w * (1.0 - self.lobe_depth * np.sin(np.pi * self.lobes * u) ** 2)
        return 0.5 * self.aspect * w


@dataclass(frozen=True)
class LeafBatch:
    """Leaves of one shape to build at once: base positions, frames and lengths."""

    positions: np.ndarray  # [m, 3]
    headings: np.ndarray  # [m, 3]
    lefts: np.ndarray  # [m, 3]
    ups: np.ndarray  # [m, 3]
    lengths: np.ndarray  # [m] metres
    tones: np.ndarray  # [m] 0 = mature colour, 1 = young (lighter) colour


def build_leaves(
    shape: LeafShape, batch: LeafBatch, rng: np.random.Generator, floor: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices [m, V, 3], faces [F, 3] of one leaf (same for all) and colours [m, V, 3].

    ``floor``: the midrib is kept above this height (a drooping leaf rests on the pot rim).
    """
    _, vertices, faces, colors = build_blades(shape, batch, rng, floor)
    return vertices, faces, colors


def build_blades(
    shape: LeafShape, batch: LeafBatch, rng: np.random.Generator, floor: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``build_leaves`` with each blade's grid of surface points first: float64
    [m, rows, cols, 3], rows along the midrib from the base (u = 0) to the tip, columns
    across from the right margin to the left, the middle column the midrib itself (the
    mesh's vertices are these points, the tip rows' collapsed to one)."""
    m, rows, cols = len(batch.lengths), shape.rows, shape.cols
    u = np.linspace(0.0, 1.0, rows)
    v = np.linspace(-1.0, 1.0, cols)
    length = batch.lengths[:, None]
    du = length / (rows - 1)

    # Midrib: march along u, bending by curl (about the blade's side) and by gravity.
    centre = np.empty((m, rows, 3))
    side = np.empty((m, rows, 3))
    normal = np.empty((m, rows, 3))
    pos, d, s, n = batch.positions.copy(), batch.headings.copy(), batch.lefts.copy(), batch.ups
    n = n.copy()
    droop = shape.droop * rng.uniform(0.7, 1.3, m)
    for i in range(rows):
        centre[:, i], side[:, i], normal[:, i] = pos, s, n
        if i == rows - 1:
            break
        angle = np.full(m, -shape.curl / (rows - 1))  # rotating about +side moves tip down
        d, n = rotate_batch(d, s, angle), rotate_batch(n, s, angle)
        axis = np.cross(d, GRAVITY)
        sin = np.linalg.norm(axis, axis=1)
        ok = sin > 1e-9
        axis[ok] /= sin[ok, None]
        axis[~ok] = s[~ok]
        bend = np.where(ok, droop * sin / (rows - 1), 0.0)
        d, s, n = (rotate_batch(x, axis, bend) for x in (d, s, n))
        pos = pos + d * du
        pos[:, 2] = np.maximum(pos[:, 2], floor)

    width = shape.half_width(u)[None, :] * length * rng.uniform(0.9, 1.1, (m, 1))  # [m, rows]
    across = v[None, None, :] * width[:, :, None]  # [m, rows, cols]
    lift = shape.fold * np.abs(across) + shape.cup * across**2 / np.maximum(
        length[:, :, None], 1e-9
    )
    if shape.ruffle:
        phase = rng.uniform(0, 2 * np.pi, (m, 1, 1))
        waves = shape.ruffle_waves * rng.uniform(0.85, 1.15, (m, 1, 1))
        edge = np.abs(v)[None, None, :] ** 2.5
        wave = np.sin(2 * np.pi * waves * u[None, :, None] + phase + 2.0 * v[None, None, :])
        wave2 = np.sin(2 * np.pi * 2.1 * waves * u[None, :, None] + 2 * phase)
        lift = lift + shape.ruffle * length[:, :, None] * edge * (wave + 0.4 * wave2)
    points = (
        centre[:, :, None, :]
        + across[..., None] * side[:, :, None, :]
        + lift[..., None] * normal[:, :, None, :]
    )
    # Tip rows collapse to one vertex each (their width is 0): no degenerate triangles.
    vertices = np.concatenate(
        [points[:, 0, cols // 2][:, None], points[:, 1:-1].reshape(m, -1, 3), points[:, -1, :1]],
        axis=1,
    )
    faces = tipped_grid_faces(rows, cols)

    colors = _leaf_colors(shape, batch.tones, u, v, rng)
    return points, vertices, faces, colors


def _leaf_colors(
    shape: LeafShape, tones: np.ndarray, u: np.ndarray, v: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    m, rows, cols = len(tones), len(u), len(v)
    base = np.asarray(shape.color)[None, :] * rng.uniform(
        1 - shape.color_jitter, 1 + shape.color_jitter, (m, 1)
    )
    base = base * (1 + rng.uniform(-0.5, 0.5, (m, 3)) * shape.color_jitter)
    young = np.asarray(shape.color) * np.array([1.35, 1.3, 1.1]) + 0.03
    base = base + tones[:, None] * (young - base)
    midrib = np.exp(-((v / 0.12) ** 2))[None, None, :, None] * (1 - u[None, :, None, None] ** 2)
    rib = np.asarray(shape.midrib_color)
    grid = base[:, None, None, :] + 0.7 * midrib * (rib - base[:, None, None, :])
    grid = grid * (1 + 0.04 * rng.standard_normal((m, rows, cols, 1)))
    colors = np.concatenate(
        [grid[:, 0, cols // 2][:, None], grid[:, 1:-1].reshape(m, -1, 3), grid[:, -1, :1]],
        axis=1,
    )
    return np.clip(colors, 0.0, 1.0)


@dataclass(frozen=True)
class PotShape:
    """A terracotta pot: truncated cone with a rolled rim, filled with soil up to z = 0."""

    top_radius: float = 0.075
    bottom_radius: float = 0.055
    depth: float = 0.11  # below the soil surface
    rim_height: float = 0.022  # of the rim band, ending rim_above above the soil
    rim_above: float = 0.012
    rim_lip: float = 0.006
    wall: float = 0.006
    segments: int = 48
    color: tuple[float, float, float] = (0.70, 0.36, 0.22)
    soil_color: tuple[float, float, float] = (0.24, 0.17, 0.11)

    @property
    def rim_top(self) -> float:
        return self.rim_above

    def soil_radius(self) -> float:
        return self.top_radius - self.wall

    def profile(self) -> np.ndarray:
        r_t, r_b, lip = self.top_radius, self.bottom_radius, self.rim_lip
        z_b, z_top = -self.depth, self.rim_above
        z_lip = z_top - self.rim_height
        r_lip_base = r_b + (r_t - r_b) * (z_lip - z_b) / (z_top - z_b)
        return np.array(
            [
                [0.0, z_b],
                [r_b, z_b],
                [r_lip_base, z_lip],
                [r_lip_base + lip, z_lip],
                [r_t + lip, z_top],
                [r_t - self.wall, z_top],
                [self.soil_radius(), 0.0],
            ]
        )


def build_pot(
    shape: PotShape, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pot vertices, faces and colours (slightly mottled terracotta, darker inside)."""
    vertices, faces = revolve(shape.profile(), shape.segments)
    colors = np.tile(np.asarray(shape.color), (len(vertices), 1))
    # The inner wall's bottom ring (at the soil) is in shadow.
    inside = np.hypot(vertices[:, 0], vertices[:, 1]) < shape.top_radius - 0.5 * shape.wall
    inside &= vertices[:, 2] < shape.rim_top - 1e-6
    colors[inside] *= 0.7
    colors *= 1 + 0.05 * rng.standard_normal((len(vertices), 1))
    return vertices, faces, np.clip(colors, 0, 1)


def build_soil(
    shape: PotShape, rng: np.random.Generator, rings: int = 16
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A flat soil disc at z = 0 filling the pot (normals up), mottled brown."""
    radius = shape.soil_radius()
    r = np.linspace(radius, 0.0, rings + 1)
    vertices, faces = revolve(np.stack([r, np.zeros_like(r)], axis=1), shape.segments)
    colors = np.asarray(shape.soil_color) * (1 + 0.25 * rng.standard_normal((len(vertices), 1)))
    return vertices, faces, np.clip(colors, 0, 1)
