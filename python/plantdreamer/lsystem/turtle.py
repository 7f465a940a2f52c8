"""3D turtle interpretation of a derived L-System string into a plant skeleton.

The turtle has a position and a right-handed frame: heading H, left L and up U (H x L = U).
It starts at the origin heading up (+z). Angles are in degrees, lengths in metres.

===========  ==========================================================================
``F(l)``     move ``l`` forward drawing a stem segment (tropism bends it, see below)
``f(l)``     move ``l`` forward without drawing (the next ``F`` starts a new stem)
``+(a)``     turn left (H towards L) about U;  ``-(a)`` turn right
``&(a)``     pitch down (H towards -U) about L;  ``^(a)`` pitch up
``\\(a)``     roll left about H;  ``/(a)`` roll right
``|``        turn around (180 degrees about U)
``$``        roll about H so that L is horizontal (U as close to world up as it can be)
``E(a)``     set the heading's elevation to ``a`` degrees above horizontal, keeping its
             azimuth, and level the frame like ``$`` (places leaf blades at a set angle)
``[`` ``]``  push / pop the turtle state (start / end a branch)
``!(r)``     set the stem radius to ``r``
``t(e)``     set the tropism elasticity to ``e`` (radians of bending per metre of stem)
organs       symbols listed in ``TurtleConfig.organs`` (e.g. ``L`` leaf) are recorded with the
             turtle frame at that point; species modules turn them into surfaces
===========  ==========================================================================

Given each module's birth step (``LSystem.derive_timed``), the skeleton keeps when each
stem point and organ appeared: a stem point is born with the ``F`` that drew it, an organ
with its symbol (the plant's growth stages, ``plant.py``).

Tropism (ABOP eq. 2.4): after each step of length ``s`` the frame rotates about H x T by
``e * s * |H x T|``, so stems bend towards the tropism vector T (gravity: (0, 0, -1)) and a
negative ``e`` bends them away from it. Long ``F`` moves are split into steps of at most
``max_step`` so the bend is smooth.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from plantdreamer.errors import InputError
from plantdreamer.lsystem.engine import Module


@dataclass(frozen=True)
class TurtleConfig:
    radius: float = 0.003
    elasticity: float = 0.0
    tropism: tuple[float, float, float] = (0.0, 0.0, -1.0)
    max_step: float = 0.01
    organs: frozenset[str] = frozenset({"L"})
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass
class StemChain:
    """A polyline drawn by consecutive ``F`` moves; ``radii`` per point; ``parent`` chain or
    -1; ``births`` per point: the derivation step of the ``F`` that drew it (the first
    point: of the ``F`` that started the chain)."""

    points: np.ndarray
    radii: np.ndarray
    parent: int
    births: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


@dataclass
class Organ:
    """An organ symbol met by the turtle, with the frame where it is inserted."""

    symbol: str
    params: tuple[float, ...]
    position: np.ndarray
    heading: np.ndarray
    left: np.ndarray
    up: np.ndarray
    chain: int  # the stem chain it grows from (-1 when there is none)
    radius: float  # stem radius at insertion
    birth: int = 0  # the derivation step that wrote its symbol


@dataclass
class Skeleton:
    chains: list[StemChain] = field(default_factory=list)
    organs: list[Organ] = field(default_factory=list)


def rotate(vectors: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotates row vectors about a unit ``axis`` by ``angle`` radians (Rodrigues)."""
    c, s = math.cos(angle), math.sin(angle)
    return vectors * c + np.cross(axis, vectors) * s + np.outer(vectors @ axis, axis) * (1 - c)


class _State:
    __slots__ = ("attach", "chain", "elasticity", "frame", "pos", "radius")

    def __init__(self, pos, frame, radius, elasticity, chain, attach):
        self.pos, self.frame, self.radius = pos, frame, radius
        self.elasticity, self.chain, self.attach = elasticity, chain, attach

    def copy(self) -> _State:
        return _State(self.pos, self.frame, self.radius, self.elasticity, self.chain, self.attach)


def interpret(
    modules: Sequence[Module], config: TurtleConfig, births: Sequence[int] | None = None
) -> Skeleton:
    """Runs the turtle over ``modules`` and returns the stems and organ insertions
    (``births``: each module's birth step, ``LSystem.derive_timed``; None: all 0)."""
    tropism = np.asarray(config.tropism, dtype=np.float64)
    norm = np.linalg.norm(tropism)
    tropism = tropism / norm if norm > 0 else tropism
    # Rows: H, L, U.
    frame = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    state = _State(
        np.asarray(config.origin, dtype=np.float64), frame, config.radius, config.elasticity, -1, -1
    )
    stack: list[_State] = []
    points: list[list[np.ndarray]] = []
    radii: list[list[float]] = []
    parents: list[int] = []
    point_births: list[list[int]] = []
    organs: list[Organ] = []

    def arg(m: Module, default: float) -> float:
        return m.params[0] if m.params else default

    for index, m in enumerate(modules):
        s = m.symbol
        birth = births[index] if births is not None else 0
        if s in "Ff":
            length = arg(m, config.max_step)
            if length <= 0:
                continue
            if s == "f":
                state.pos = state.pos + state.frame[0] * length
                state.chain = -1
                continue
            if state.chain < 0:
                points.append([state.pos])
                radii.append([state.radius])
                parents.append(state.attach)
                point_births.append([birth])
                state.chain = state.attach = len(points) - 1
            steps = max(1, math.ceil(length / config.max_step - 1e-9))
            step = length / steps
            for _ in range(steps):
                state.pos = state.pos + state.frame[0] * step
                points[state.chain].append(state.pos)
                radii[state.chain].append(state.radius)
                point_births[state.chain].append(birth)
                if state.elasticity and norm > 0:
                    state.frame = _bend(state.frame, tropism, state.elasticity * step)
        elif s in "+-&^\\/|":
            angle = math.radians(arg(m, 180.0 if s == "|" else 0.0))
            h, left, up = state.frame
            if s in "+-|":
                state.frame = rotate(state.frame, up, angle if s != "-" else -angle)
            elif s in "&^":
                state.frame = rotate(state.frame, left, angle if s == "&" else -angle)
            else:
                state.frame = rotate(state.frame, h, angle if s == "\\" else -angle)
        elif s == "$":
            state.frame = _level(state.frame)
        elif s == "E":
            state.frame = _elevate(state.frame, math.radians(arg(m, 0.0)))
        elif s == "[":
            stack.append(state.copy())
            state.chain = -1
        elif s == "]":
            if not stack:
                raise InputError("unbalanced ']' in the L-System string")
            state = stack.pop()
        elif s == "!":
            state.radius = max(arg(m, state.radius), 0.0)
        elif s == "t":
            state.elasticity = arg(m, 0.0)
        elif s in config.organs:
            h, left, up = state.frame
            organs.append(
                Organ(s, m.params, state.pos, h, left, up, state.attach, state.radius, birth)
            )
    if stack:
        raise InputError("unbalanced '[' in the L-System string")
    chains = [
        StemChain(np.array(p), np.array(r), parent, np.array(b, dtype=np.int64))
        for p, r, parent, b in zip(points, radii, parents, point_births, strict=True)
    ]
    return Skeleton(chains, organs)


def _bend(frame: np.ndarray, tropism: np.ndarray, strength: float) -> np.ndarray:
    axis = np.cross(frame[0], tropism)
    sin = float(np.linalg.norm(axis))
    if sin < 1e-9:
        return frame
    return rotate(frame, axis / sin, strength * sin)


def _level(frame: np.ndarray) -> np.ndarray:
    h = frame[0]
    left = np.cross(np.array([0.0, 0.0, 1.0]), h)
    n = np.linalg.norm(left)
    if n < 1e-9:  # heading vertical: any roll is level
        return frame
    left = left / n
    return np.array([h, left, np.cross(h, left)])


def _elevate(frame: np.ndarray, elevation: float) -> np.ndarray:
    h, _, up = frame
    azimuth = np.array([h[0], h[1], 0.0])
    if np.linalg.norm(azimuth) < 1e-6:  # heading vertical: lean towards -U
        azimuth = np.array([-up[0], -up[1], 0.0])
        if np.linalg.norm(azimuth) < 1e-6:
            azimuth = np.array([1.0, 0.0, 0.0])
    azimuth /= np.linalg.norm(azimuth)
    h = azimuth * math.cos(elevation) + np.array([0.0, 0.0, math.sin(elevation)])
    left = np.array([-azimuth[1], azimuth[0], 0.0])  # z x azimuth
    return np.array([h, left, np.cross(h, left)])
