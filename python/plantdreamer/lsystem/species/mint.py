"""Mint (Mentha), a potted clump of upright shoots.

Like the authors' mint (3-7 stems, each extra stem with probability 0.75, stems rolled by
about 130 degrees and tilted by rand(17, 22) degrees), one stem starts per step at a random
spot near the pot centre, leans outwards and bends back up. Stems are square (4-sided tubes).
Every node carries an opposite pair of short-stalked, serrated ovate leaves, and successive
pairs are rolled by 90 degrees (decussate). Leaves and internodes grow with age, so leaves
shrink towards the young shoot tips. A per-plant vigour ``v`` (and a per-stem factor)
scales leaves and internodes.
"""

from __future__ import annotations

import math

from plantdreamer.lsystem.engine import Rule
from plantdreamer.lsystem.organs import LeafShape
from plantdreamer.lsystem.species.base import Species
from plantdreamer.lsystem.turtle import TurtleConfig

STEPS = 12


def _internode(age: float) -> float:
    return 0.03 * (1.0 - math.exp(-age / 2.0))


def _leaf(age: float) -> float:
    return 0.048 * (1.0 - math.exp(-age / 2.5))


def _tone(age: float) -> float:
    return math.exp(-(age - 1.0) / 1.5)


# A leaf of the pair at a node of age {a}; {pitch} is & or ^ (the two opposite sides).
_LEAF = (
    "[ {pitch}(rand(40,52) + 14*(1-tone({a}))) !(0.0007) F(0.004) $"
    " L(v*leaf({a})*rand(0.9,1.1), tone({a})) ]"
)
_NODE = (
    "!(0.0011 + 0.0009*(1-tone(N-i))) F(v*internode(N-i)*rand(0.85,1.15)) "
    + _LEAF.format(pitch="&", a="(N-i)")
    + " "
    + _LEAF.format(pitch="^", a="(N-i)")
    + " /(rand(84,96)) M(i+1, v)"
)
# A new stem: step out from the centre, lean outwards by rand(17, 22) degrees.
_STEM = "[ &(90) f(rand(0.006,0.035)) ^(90) &(rand(17,22)) /(rand(0,90)) t(-9) M(k+1, v*rand(0.8,1.1)) ]"

SPECIES = Species(
    name="mint",
    summary="3-7 upright square stems, opposite decussate serrated ovate leaves",
    axiom="X(0, rand(0.8,1.15))",
    rules=(
        Rule("X(k, v)", f"{_STEM} /(rand(115,145)) X(k+1, v)", "k < 3"),
        Rule("X(k, v)", f"{_STEM} /(rand(115,145)) X(k+1, v)", "3 <= k < 7", 0.75),
        Rule("X(k, v)", "", "3 <= k < 7", 0.25),
        Rule("M(i, v)", _NODE, "i < N"),
    ),
    iterations=STEPS,
    constants={"N": STEPS, "internode": _internode, "leaf": _leaf, "tone": _tone},
    turtle=TurtleConfig(radius=0.002, max_step=0.01, origin=(0, 0, -0.01)),
    leaves={
        "L": LeafShape(
            aspect=0.68,
            widest=0.36,
            roundness=0.85,
            tip_taper=0.3,
            teeth=9,
            tooth_depth=0.14,
            fold=0.18,
            cup=0.05,
            curl=-0.25,
            droop=0.4,
            color=(0.20, 0.45, 0.13),
            midrib_color=(0.34, 0.55, 0.22),
            rows=37,
            cols=9,
        )
    },
    stem_sides=4,
    stem_color=(0.32, 0.44, 0.18),
    stem_base_color=(0.38, 0.30, 0.22),
    height_range=(0.17, 0.40),
    leaf_range=(50, 140),
)
