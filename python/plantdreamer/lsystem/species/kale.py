"""Kale (Brassica oleracea var. sabellica), a young potted rosette.

A short, thick stem makes one leaf per step (10 steps, as the authors' kale), each rolled
by about the golden angle (137.5 degrees), so leaves spiral around the stem near the soil.
Each leaf is a long, pale petiole and an oblong-obovate blade with a strongly ruffled
(curly) margin. Leaf size falls by a factor 0.85 per step (the authors' width ratio), so the
old outer leaves are large and spread out and the young inner ones are small and upright.
The two oldest leaves may have withered away (p = 0.2 each), leaving 8-10 leaves. A
per-plant vigour ``v`` (rand(0.8, 1.2)) scales the leaves.
"""

from __future__ import annotations

from plantdreamer.lsystem.engine import Rule
from plantdreamer.lsystem.organs import LeafShape
from plantdreamer.lsystem.species.base import Species
from plantdreamer.lsystem.turtle import TurtleConfig

STEPS = 10
RATIO = 0.85

# Leaf i: outer (old) leaves leave the stem 44 degrees above horizontal, inner ones 76.
_LEAF = (
    "[ &(46 - 3.6*i + rand(-5,5)) !(0.0012 + 0.0025*r**i) t(1) F(v*0.07*r**i*rand(0.9,1.1)) $"
    " L(v*0.17*r**i*rand(0.9,1.1), i/N) ]"
)

SPECIES = Species(
    name="kale",
    summary="rosette of long-petioled, curly-edged leaves diminishing in size",
    axiom="!(0.006) K(0, rand(0.8,1.2))",
    rules=(
        Rule("K(i, v)", f"F(0.0035) /(137.5 + rand(-8,8)) {_LEAF} K(i+1, v)", "2 <= i < N"),
        # The two oldest leaves may have withered and been removed (p = 0.2 each).
        Rule("K(i, v)", f"F(0.0035) /(137.5 + rand(-8,8)) {_LEAF} K(i+1, v)", "i < 2", 0.8),
        Rule("K(i, v)", "F(0.0035) /(137.5 + rand(-8,8)) K(i+1, v)", "i < 2", 0.2),
    ),
    iterations=STEPS,
    constants={"N": STEPS, "r": RATIO},
    turtle=TurtleConfig(radius=0.008, max_step=0.01, origin=(0, 0, -0.01)),
    leaves={
        "L": LeafShape(
            aspect=0.62,
            widest=0.6,
            roundness=1.1,
            lobes=4.5,
            lobe_depth=0.12,
            fold=0.25,
            cup=0.1,
            curl=0.15,
            droop=0.7,
            ruffle=0.035,
            ruffle_waves=12.0,
            color=(0.15, 0.34, 0.15),
            midrib_color=(0.55, 0.68, 0.45),
            rows=128,
            cols=17,
        )
    },
    stem_sides=12,
    stem_color=(0.52, 0.62, 0.40),
    height_range=(0.09, 0.22),
    leaf_range=(8, 10),
)
