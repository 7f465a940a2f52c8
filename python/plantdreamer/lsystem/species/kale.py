"""Kale (Brassica oleracea var. sabellica), a young potted rosette.

A short, thick stem makes one leaf per step (10 steps, as the authors' kale), each rolled
by about the golden angle (137.5 degrees), so leaves spiral around the stem near the soil.
Each leaf is a long, pale petiole and an oblong-obovate blade with a strongly ruffled
(curly) margin. Leaf size falls by a factor 0.85 per step (the authors' width ratio), so the
old outer leaves are large and spread out and the young inner ones are small and upright.
"""

from __future__ import annotations

from plantdreamer.lsystem.engine import Rule
from plantdreamer.lsystem.organs import LeafShape
from plantdreamer.lsystem.species.base import Species
from plantdreamer.lsystem.turtle import TurtleConfig

STEPS = 10
RATIO = 0.85

_LEAF = (
    "[ &(62 - 4.8*i + rand(-5,5)) !(0.0012 + 0.0028*r**i) t(3) F(0.085*r**i*rand(0.9,1.1)) $"
    " L(0.16*r**i*rand(0.9,1.1), i/N) ]"
)

SPECIES = Species(
    name="kale",
    summary="rosette of long-petioled, curly-edged leaves diminishing in size",
    axiom="!(0.008) K(0)",
    rules=(
        Rule("K(i)", f"F(0.005) /(137.5 + rand(-8,8)) {_LEAF} K(i+1)", "i < N"),
    ),
    iterations=STEPS,
    constants={"N": STEPS, "r": RATIO},
    turtle=TurtleConfig(radius=0.008, max_step=0.01, origin=(0, 0, -0.01)),
    leaves={
        "L": LeafShape(
            aspect=0.5,
            widest=0.62,
            roundness=0.9,
            fold=0.25,
            cup=0.1,
            curl=0.1,
            droop=1.0,
            ruffle=0.05,
            ruffle_waves=9.0,
            color=(0.15, 0.34, 0.15),
            midrib_color=(0.55, 0.68, 0.45),
            rows=48,
            cols=17,
        )
    },
    stem_sides=12,
    stem_color=(0.52, 0.62, 0.40),
    height_range=(0.1, 0.45),
    leaf_range=(10, 10),
)
