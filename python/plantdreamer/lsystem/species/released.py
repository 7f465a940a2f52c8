"""The authors' released plant structures, as variants of our species (docs/fidelity.md).

Their grammars (``l_systems/{bean,kale,mint}.py``) are rewritten a fixed number of times by
the Blender L-System add-on ``krljg/lsystem``: every module with a matching rule is replaced
once per pass (a random choice among matching rules), and symbols with no turtle meaning that
are still unexpanded after the last pass are not drawn. Written here as the same productions
in our engine, run for the same number of passes, in metres, with our organ shapes (their
leaves were hand-made Blender models). Their leaf placeholders (``X``, ``Y``, ``Z``) become our
leaf organs one pass later, exactly when theirs become ``~(leaf)`` copies, so a leaf that is
still a placeholder after the last pass is missing, as in theirs. Counts this gives:

- ``bean-released`` (7 passes): the stem's internodes taper 6, 5, 4, 3, 2, 1 steps above
  the 5-step base, each node after turning up 30 degrees and rolling rand(100, 160); each
  node is a 70-degree petiole of 2 steps ending in a leaf pair, but only nodes 1-4 have grown
  their pair, node 5 has a bare bud and node 6 a petiole stub; 3 small apex leaves (their
  per-plant angle counts ``{amp}``, ``{up}``, ``{slash}``: 10-50 degrees). 11 leaves. The
  authors roll the two leaves of a pair 50 degrees apart; here they are turned 25 degrees
  either way so both blades can be levelled face up, as every species' leaves are.
- ``kale-released`` (10 passes, angle 25): a stem rising 0.6 + 0.4 units per leaf, radius 0.1
  per unit shrinking by 0.85 a half-step; each leaf on a petiole leaving at rand(90, 100)
  degrees and pitched back up 25 degrees; the 5th leaf is still a placeholder: 4 leaves.
  Their script grows ``instances=10`` plants in a row; one plant is one sample here.
- ``mint-released`` (20 passes): 3 stems plus 4 more with p = 0.75 each (3-7), a bare base of
  2 units, then 9 zig-zag nodes a stem (roll 130, pitch up rand(17, 22), back down
  rand(10, 15)), one alternate leaf a node: 9 leaves a stem. Their first nodes carry the
  ``tmleaf`` model (``T`` here) and later ones ``mleaf`` (``L``): node counter t >= 2 gives
  ``T``, t < 0 ``L``, t = 0 or 1 either with p = 0.5 (both of their rules match), so the
  first 2-4 leaves of a 4-node-counter stem and 1-3 of a 3-node-counter stem are ``T``.
  Both models' shapes are ours (the mint leaf); the symbol keeps which one was placed.
"""

from __future__ import annotations

from plantdreamer.lsystem.engine import Rule
from plantdreamer.lsystem.species.base import Species
from plantdreamer.lsystem.species.bean import SPECIES as OUR_BEAN
from plantdreamer.lsystem.species.kale import SPECIES as OUR_KALE
from plantdreamer.lsystem.species.mint import SPECIES as OUR_MINT
from plantdreamer.lsystem.turtle import TurtleConfig

BEAN_PASSES = 7  # their min_iterations
KALE_PASSES = 10
MINT_PASSES = 20
BEAN_LEAVES = 11  # 4 grown pairs + 3 apex leaves
KALE_LEAVES = 4
MINT_LEAVES_PER_STEM = 9

_BEAN_STEP = 0.012  # metres per F of the authors' bean (their length=0.5)
BEAN = Species(
    name="bean-released",
    prompt_name="bean",
    summary="the authors' bean: tapering internodes, 4 grown leaf pairs, 3 apex leaves",
    # a, w, s: their per-plant {amp}, {up}, {slash} (1-5 turns of their 10-degree angle).
    axiom="!(0.003) /(rand(0,360)) I(5) A(5, 10*randint(1,5), 10*randint(1,5), 10*randint(1,5))",
    rules=(
        Rule(
            "A(t, a, w, s)", "[ &(70) B(w) ] /(rand(100,160)) I(10) ^(30) A(t-1, a, w, s)", "t > 0"
        ),
        Rule(
            "A(t, a, w, s)",
            "[ &(70) B(w) ] /(rand(100,160)) I(10) A(t-1, a, w, s)"
            " &(a) Y ^(w) /(s) \\(10) Y ^(30) /(20) \\(40) Y",
            "t == 0",
        ),
        Rule("I(t)", "F(u) I(t-1)", "t > 0"),
        Rule("B(w)", "!(0.0012) F(u) C(w)"),
        Rule("C(w)", "F(u) ^(30 + w) X"),
        Rule("X", "[ +(25) $ L(0.075, 0.3) ] [ -(25) $ L(0.075, 0.3) ]"),
        Rule("Y", "[ $ S(0.03, 1) ]"),
    ),
    iterations=BEAN_PASSES,
    constants={"u": _BEAN_STEP},
    turtle=TurtleConfig(radius=0.003, max_step=0.012, origin=(0, 0, -0.01), organs=frozenset("LS")),
    leaves={"L": OUR_BEAN.leaves["L"], "S": OUR_BEAN.leaves["L"]},
    stem_color=OUR_BEAN.stem_color,
    stem_base_color=OUR_BEAN.stem_base_color,
    height_range=(0.10, 0.40),
    leaf_range=(BEAN_LEAVES, BEAN_LEAVES),
)

_KALE_UNIT = 0.02  # metres per unit of the authors' kale
KALE = Species(
    name="kale-released",
    prompt_name="kale",
    summary="the authors' kale: a stem rising one unit per leaf, 4 near-horizontal leaves",
    axiom="[ A(5, 0.1*u) ]",
    rules=(
        # Their A ignores its counter t: the plant stops when the passes run out.
        Rule(
            "A(t, w)",
            "!(w) /(rand(0,360)) $ F(0.6*u) [ &(rand(90,100)) /(rand(-45,45)) +(rand(-30,30))"
            " B(0.5*u, w*r) ] -(4) /(rand(-45,45)) D(t-1, w*r)",
        ),
        Rule("B(l, w)", "!(w) ^(25) F(l) P"),
        Rule("P", "F(0.05*u) L(0.11, 0.2)"),
        Rule(
            "D(t, w)",
            "!(w) F(0.4*u) [ &(rand(90,100)) /(rand(-45,45)) ] +(5) /(rand(-45,45)) A(t-1, w*r)",
        ),
    ),
    iterations=KALE_PASSES,
    constants={"u": _KALE_UNIT, "r": 0.85},
    turtle=TurtleConfig(radius=0.002, max_step=0.01, origin=(0, 0, -0.01)),
    leaves={"L": OUR_KALE.leaves["L"]},
    stem_sides=12,
    stem_color=OUR_KALE.stem_color,
    height_range=(0.03, 0.20),
    leaf_range=(KALE_LEAVES, KALE_LEAVES),
)

_MINT_UNIT = 0.03  # metres per unit of the authors' mint
# Their optional stems are added to the axiom (p = 0.75 each) before rewriting; here X(k)
# adds one in the first pass already rewritten once (A(t) -> F(u) B(t) draws nothing).
_MINT_OPTIONAL = (
    "/(75) [ -(90) F(0.75*u) +(85) F(u) F(u) B(4) ]",
    "/(75) [ &(90) F(0.75*u) ^(85) F(u) F(u) B(4) ]",
    "/(75) [ -(90) F(1.5*u) +(85) F(0.5*u) F(u) B(3) ]",
    "/(75) [ &(90) F(1.5*u) ^(85) F(0.5*u) F(u) B(3) ]",
)
_MINT_NODE = "F(0.5*u) &(rand(10,15)) B(t)"
MINT = Species(
    name="mint-released",
    prompt_name="mint",
    summary="the authors' mint: 3-7 zig-zag stems, 9 alternate leaves a stem, two leaf models",
    axiom="!(0.05*u) /(rand(0,360)) [ F(u) A(4) ] /(120) [ +(90) F(u) -(90) F(u) A(4) ]"
    " /(120) [ ^(90) F(u) &(90) F(u) A(4) ] "
    + " ".join(f"X({k})" for k in range(len(_MINT_OPTIONAL))),
    rules=(
        *(Rule("X(k)", stem, f"k == {k}", 0.75) for k, stem in enumerate(_MINT_OPTIONAL)),
        Rule("X(k)", "", None, 0.25),
        Rule("A(t)", "F(u) B(t)"),
        Rule("B(t)", "F(0.5*u) /(130) ^(rand(17,22)) [ C(t-1) ]"),
        Rule("C(t)", f"{_MINT_NODE} [ M ]", "t < 0"),
        Rule("C(t)", f"{_MINT_NODE} [ M ]", "0 <= t < 2", 0.5),
        Rule("C(t)", f"{_MINT_NODE} [ Z ]", "0 <= t < 2", 0.5),
        Rule("C(t)", f"{_MINT_NODE} [ Z ]", "t >= 2"),
        Rule("M", "F(0.1*u) $ L(0.035, 0.3)"),
        Rule("Z", "F(0.1*u) $ T(0.035, 0.3)"),
    ),
    iterations=MINT_PASSES,
    constants={"u": _MINT_UNIT},
    turtle=TurtleConfig(radius=0.0015, max_step=0.01, origin=(0, 0, -0.01), organs=frozenset("LT")),
    leaves={"L": OUR_MINT.leaves["L"], "T": OUR_MINT.leaves["L"]},
    stem_sides=6,
    stem_color=OUR_MINT.stem_color,
    stem_base_color=OUR_MINT.stem_base_color,
    height_range=(0.10, 0.45),
    leaf_range=(3 * MINT_LEAVES_PER_STEM, 7 * MINT_LEAVES_PER_STEM),
)

SPECIES = (BEAN, MINT, KALE)
