"""The authors' released plant structures, as variants of our species (docs/fidelity.md).

The paper's synthetic plants came from these structures; written here from their structure
facts, in metres, with our organ shapes (their leaves were hand-made Blender models):

- ``bean-released``: 6 nodes up a main stem that turns up by 30 degrees after each node
  and rolls rand(100, 160) degrees between nodes; each node is a petiole leaving at 70 degrees
  and ending in a leaf pair (a per-plant 10-50 degree upturn; the authors roll the two leaves
  50 degrees apart, here they are turned 25 degrees either way so both blades can be levelled
  face up, as every species' leaves are); 3 small leaves at the apex. 15 leaves: 12 in pairs,
  3 small.
- ``mint-released``: 3 stems plus 4 more with p = 0.75 each (3-7), each a zig-zag of 9
  nodes (roll 130, pitch up rand(17, 22), pitch back rand(10, 15)) with one alternate leaf per
  node on a short stalk: 9 leaves per stem.
- ``kale-released``: a stem rising one unit per leaf (0.6 + 0.4), each leaf on a petiole
  leaving at rand(90, 100) degrees (near horizontal), every leaf the same size; the stem
  radius shrinks by 0.85 per half-step. 10 derivation steps give 5 leaves.
"""

from __future__ import annotations

from plantdreamer.lsystem.engine import Rule
from plantdreamer.lsystem.species.base import Species
from plantdreamer.lsystem.species.bean import SPECIES as OUR_BEAN
from plantdreamer.lsystem.species.kale import SPECIES as OUR_KALE
from plantdreamer.lsystem.species.mint import SPECIES as OUR_MINT
from plantdreamer.lsystem.turtle import TurtleConfig

BEAN_NODES = 6
BEAN_APEX_LEAVES = 3
MINT_NODES = 9  # per stem
KALE_LEAVES = 5

_BEAN_UNIT = 0.011  # metres per unit of the authors' grammar
_BEAN_PETIOLE = (
    "[ &(70) !(0.0012) F(2*u) F(2*u) ^(30 + w)"
    " [ +(25) $ L(0.075, 0.3) ] [ -(25) $ L(0.075, 0.3) ] ]"
)
_BEAN_APEX = (
    "&(rand(10,50)) [ $ S(0.03, 1) ] ^(w) /(rand(10,50)) \\(10) [ $ S(0.03, 1) ]"
    " ^(30) /(20) \\(40) $ S(0.03, 1)"
)

BEAN = Species(
    name="bean-released",
    summary="the authors' bean: 6 nodes, each a 70-degree petiole with a leaf pair, 3 apex leaves",
    axiom="!(0.003) /(rand(0,360)) F(5*u) A(5, 10*randint(1,5))",
    rules=(
        Rule("A(t, w)", f"{_BEAN_PETIOLE} /(rand(100,160)) F(5*u) ^(30) A(t-1, w)", "t > 0"),
        Rule("A(t, w)", f"{_BEAN_PETIOLE} /(rand(100,160)) F(5*u) {_BEAN_APEX}", "t == 0"),
    ),
    iterations=BEAN_NODES,
    constants={"u": _BEAN_UNIT},
    turtle=TurtleConfig(radius=0.003, max_step=0.012, origin=(0, 0, -0.01), organs=frozenset("LS")),
    leaves={"L": OUR_BEAN.leaves["L"], "S": OUR_BEAN.leaves["L"]},
    stem_color=OUR_BEAN.stem_color,
    stem_base_color=OUR_BEAN.stem_base_color,
    height_range=(0.10, 0.50),
    leaf_range=(15, 15),
)

_MINT_UNIT = 0.03
# A stem: its start (straight up, or out then up), then nodes M(0..8).
_MINT_STEMS = (
    "[ F(u) M(0) ]",
    "[ +(90) F(u) -(90) F(u) M(0) ]",
    "[ ^(90) F(u) &(90) F(u) M(0) ]",
    "[ -(90) F(0.75*u) +(85) F(u) M(0) ]",
    "[ &(90) F(0.75*u) ^(85) F(u) M(0) ]",
    "[ -(90) F(1.5*u) +(85) F(0.5*u) M(0) ]",
    "[ &(90) F(1.5*u) ^(85) F(0.5*u) M(0) ]",
)
_MINT_ROLLS = ("", "/(120)", "/(120)", "/(75)", "/(75)", "/(75)", "/(75)")

MINT = Species(
    name="mint-released",
    summary="the authors' mint: 3-7 zig-zag stems, one alternate leaf per node",
    axiom="!(0.0015) /(rand(0,360)) " + " ".join(f"X({k})" for k in range(7)),
    rules=tuple(
        Rule("X(k)", f"{roll} {stem}", f"k == {k}", 1.0 if k < 3 else 0.75)
        for k, (roll, stem) in enumerate(zip(_MINT_ROLLS, _MINT_STEMS, strict=True))
    )
    + tuple(Rule("X(k)", "", f"k == {k}", 0.25) for k in range(3, len(_MINT_STEMS)))
    + (
        Rule(
            "M(i)",
            "F(0.5*u) /(130) ^(rand(17,22)) [ F(0.5*u) &(rand(10,15)) M(i+1) ]"
            " [ F(0.1*u) $ L(0.035, 0.3) ]",
            "i < N",
        ),
    ),
    iterations=MINT_NODES + 1,
    constants={"u": _MINT_UNIT, "N": MINT_NODES},
    turtle=TurtleConfig(radius=0.0015, max_step=0.01, origin=(0, 0, -0.01)),
    leaves={"L": OUR_MINT.leaves["L"]},
    stem_sides=6,
    stem_color=OUR_MINT.stem_color,
    stem_base_color=OUR_MINT.stem_base_color,
    height_range=(0.10, 0.45),
    leaf_range=(3 * MINT_NODES, 7 * MINT_NODES),
)

_KALE_UNIT = 0.02
KALE = Species(
    name="kale-released",
    summary="the authors' kale: a stem rising one unit per leaf, near-horizontal leaves of one size",
    axiom="A(0, 0.006)",
    rules=(
        Rule(
            "A(i, w)",
            "!(w) /(rand(0,360)) $ F(0.6*u) [ &(rand(90,100)) /(rand(-45,45)) +(rand(-30,30))"
            " !(w*r) ^(10) F(0.5*u) L(0.11, 0.2) ] -(4) /(rand(-45,45))"
            " !(w*r) F(0.4*u) +(5) /(rand(-45,45)) A(i+1, w*r*r)",
            "i < N",
        ),
    ),
    iterations=KALE_LEAVES,
    constants={"u": _KALE_UNIT, "r": 0.85, "N": KALE_LEAVES},
    turtle=TurtleConfig(radius=0.006, max_step=0.01, origin=(0, 0, -0.01)),
    leaves={"L": OUR_KALE.leaves["L"]},
    stem_sides=12,
    stem_color=OUR_KALE.stem_color,
    height_range=(0.05, 0.25),
    leaf_range=(KALE_LEAVES, KALE_LEAVES),
)

SPECIES = (BEAN, MINT, KALE)
