"""Common bean (Phaseolus vulgaris, bush type), a young potted plant.

An upright main stem grows one node per step (the authors' bean used at least 7 steps; we
use 8). Successive nodes are rolled by rand(100, 160) degrees, so the trifoliate leaves
alternate around the stem. Each leaf is a petiole ending in a rachis with two opposite lateral
leaflets and a terminal one: broad ovate leaflets with an acuminate tip. Lower nodes may
carry a lateral branch at about 70 degrees (``&(70)``) that bends upwards and bears 1-3
smaller leaves. Leaves and internodes are sized by their age (steps since they appeared),
so the top of the plant is small and young. A per-plant vigour ``v`` (rand(0.8, 1.15), set in
the axiom) scales every length, so plants of one species differ in size as well as shape.
"""

from __future__ import annotations

import math

from plantdreamer.lsystem.engine import Rule
from plantdreamer.lsystem.organs import LeafShape
from plantdreamer.lsystem.species.base import Species
from plantdreamer.lsystem.turtle import TurtleConfig

NODES = 8  # main-stem nodes = derivation steps


def _internode(age: float) -> float:
    return 0.052 * (1.0 - math.exp(-(age + 0.3) / 1.8))


def _leaflet(age: float) -> float:
    return 0.085 * (1.0 - math.exp(-(age + 0.4) / 1.6))


def _petiole(age: float) -> float:
    return 0.085 * (1.0 - math.exp(-(age + 0.2) / 2.0))


def _tone(age: float) -> float:
    return math.exp(-(age - 1.0) / 1.3)


def _stem_radius(age: float) -> float:
    return 0.0014 + 0.0019 * (1.0 - math.exp(-age / 3.0))


# One node of age {a} (steps it will have grown when the derivation ends), scaled by {k}:
# a stem segment, a roll of rand(100, 160) degrees, and a trifoliate leaf (petiole, two
# opposite lateral leaflets, a short rachis and the terminal leaflet).
_NODE = (
    "+(rand(-7,7)) !({k}*stem_radius({a})) F(v*{k}*internode({a})*rand(0.85,1.15))"
    " /(rand(100,160))"
    " [ &(rand(38,52)) !(0.0008+0.0006*{k}) t(2) F(v*{k}*petiole({a})) $"
    " [ +(rand(62,78)) E(rand(-10,8)) L(0.8*v*{k}*leaflet({a}), tone({a})) ]"
    " [ -(rand(62,78)) E(rand(-10,8)) L(0.8*v*{k}*leaflet({a}), tone({a})) ]"
    " F(0.13*v*{k}*leaflet({a})) E(rand(-5,15)) L(v*{k}*leaflet({a}), tone({a})) ]"
)
_MAIN = _NODE.format(k="1", a="(N-i)")
_LATERAL = _NODE.format(k="0.75", a="(N-i)")
_BRANCH = "[ &(70) t(-4) B(i+1, 0, v, randint(1, 3)) ]"

SPECIES = Species(
    name="bean",
    summary="upright stem, alternate trifoliate leaves with broad ovate leaflets",
    axiom="!(0.0033) t(-2) F(rand(0.035,0.055)) A(0, rand(0.8,1.15))",
    rules=(
        # Main-stem apex: a node with a trifoliate leaf; lower nodes may branch (p = 0.45).
        Rule("A(i, v)", f"{_MAIN} {_BRANCH} A(i+1, v)", "1 <= i <= 3", 0.45),
        Rule("A(i, v)", f"{_MAIN} A(i+1, v)", "1 <= i <= 3", 0.55),
        Rule("A(i, v)", f"{_MAIN} A(i+1, v)", "i < 1 or (3 < i < N)"),
        # Lateral branch apex: m = 1-3 smaller nodes.
        Rule("B(i, n, v, m)", f"{_LATERAL} B(i+1, n+1, v, m)", "i < N and n < m"),
    ),
    iterations=NODES,
    constants={
        "N": NODES,
        "internode": _internode,
        "leaflet": _leaflet,
        "petiole": _petiole,
        "tone": _tone,
        "stem_radius": _stem_radius,
    },
    turtle=TurtleConfig(radius=0.0033, elasticity=-2.0, max_step=0.012, origin=(0, 0, -0.01)),
    leaves={
        "L": LeafShape(
            aspect=0.74,
            widest=0.36,
            roundness=0.7,
            tip_taper=0.6,
            fold=0.12,
            cup=0.12,
            curl=-0.2,
            droop=0.5,
            color=(0.19, 0.39, 0.10),
            midrib_color=(0.36, 0.54, 0.20),
            rows=16,
            cols=9,
        )
    },
    stem_sides=8,
    stem_color=(0.36, 0.54, 0.20),
    stem_base_color=(0.42, 0.40, 0.20),
    height_range=(0.30, 0.55),
    leaf_range=(24, 54),
)
