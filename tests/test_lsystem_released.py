"""The authors' released L-System structures: counts and proportions over seeds.

The expected numbers are those of the authors' grammars rewritten the way the Blender add-on
they use does (a fixed number of passes, placeholders left after the last pass not drawn):
docs/fidelity.md lists them with the grammar lines.
"""

import numpy as np
import pytest

from plantdreamer.lsystem import grow, list_species
from plantdreamer.lsystem.plant import _streams
from plantdreamer.lsystem.species import get_species

SEEDS = range(5)


def derive(name, seed):
    """The derived string ``grow`` interprets for this seed (the same grammar stream)."""
    spec = get_species(name)
    return spec.lsystem.derive(spec.iterations, _streams(seed)[0])


def top_level(modules):
    """The modules outside any branch, a branch shown as one ``[]`` module."""
    out, depth = [], 0
    for m in modules:
        if m.symbol == "[":
            if depth == 0:
                out.append("[]")
            depth += 1
        elif m.symbol == "]":
            depth -= 1
        elif depth == 0:
            out.append(m)
    return out


def branches(modules):
    """Each top-level branch's modules (nested ones included)."""
    out, depth = [], 0
    for m in modules:
        if m.symbol == "[":
            if depth == 0:
                out.append([])
            depth += 1
            if depth > 1:
                out[-1].append(m)
        elif m.symbol == "]":
            depth -= 1
            if depth:
                out[-1].append(m)
        elif depth:
            out[-1].append(m)
    return out


def test_released_variants_are_registered_beside_ours_with_their_plant_names():
    assert {"bean-released", "mint-released", "kale-released"} <= set(list_species())
    for name in ("bean", "kale", "mint"):
        assert get_species(f"{name}-released").plant_name == name
        assert get_species(name).plant_name == name


@pytest.mark.parametrize("seed", SEEDS)
def test_bean_has_11_leaves_tapering_internodes_and_2_step_petioles(seed):
    plant = grow("bean-released", seed)
    symbols = [o.symbol for o in plant.leaves]
    assert symbols.count("L") == 8 and symbols.count("S") == 3  # 4 grown pairs + apex
    modules = derive("bean-released", seed)
    # Main stem: a 5-step base, then 6 nodes with internodes of 6, 5, 4, 3, 2, 1 steps.
    runs, run = [], 0
    for m in top_level(modules):
        if m == "[]":
            runs.append(run)
            run = 0
        elif m.symbol == "F":
            run += 1
    assert runs[:7] == [5, 6, 5, 4, 3, 2, 1]
    step = get_species("bean-released").constants["u"]
    # Petioles: 6 at 70 degrees; each grown one is 2 steps; node 5 is a bare bud, node 6 a stub.
    petioles = [b for b in branches(modules) if b[0].symbol == "&" and b[0].params == (70.0,)]
    assert len(petioles) == 6
    steps = [sum(m.symbol == "F" for m in b[:4]) for b in petioles]
    assert steps == [2, 2, 2, 2, 2, 1]
    assert all(m.params == (step,) for b in petioles for m in b if m.symbol == "F")
    assert [any(m.symbol == "X" for m in b) for b in petioles] == [False] * 4 + [True, False]
    # The two leaves of a pair sit at the same petiole tip.
    pairs = np.array([o.position for o in plant.leaves if o.symbol == "L"]).reshape(4, 2, 3)
    np.testing.assert_allclose(pairs[:, 0], pairs[:, 1], atol=1e-9)


@pytest.mark.parametrize("seed", SEEDS)
def test_kale_has_4_leaves_pitched_up_25_degrees_on_a_thin_stem(seed):
    plant = grow("kale-released", seed)
    assert len(plant.leaves) == 4
    assert len({o.params[0] for o in plant.leaves}) == 1  # one size
    modules = derive("kale-released", seed)
    assert sum(m.symbol == "P" for m in modules) == 1  # the 5th leaf is still a placeholder
    assert [m.params for m in modules if m.symbol == "^"] == [(25.0,)] * 5
    # Stem radius 0.1 per unit of stem, shrinking by 0.85 per half-step.
    unit = get_species("kale-released").constants["u"]
    stem = top_level(branches(modules)[0])  # the plant is one branch, as in theirs
    radii = [m.params[0] for m in stem if m != "[]" and m.symbol == "!"]
    np.testing.assert_allclose(radii[:3], np.array([1, 0.85, 0.85**2]) * 0.1 * unit)
    heights = np.sort([o.position[2] for o in plant.leaves])
    np.testing.assert_allclose(np.diff(heights), unit, atol=0.2 * unit)  # one unit per leaf


def test_mint_has_3_to_7_stems_of_9_leaves_with_two_leaf_models():
    stems, firsts = set(), set()
    for seed in range(12):
        modules = derive("mint-released", seed)
        per_stem = [[m.symbol for m in b if m.symbol in "LT"][::-1] for b in branches(modules)]
        assert sum(map(len, per_stem)) == len(grow("mint-released", seed).leaves)
        assert 3 <= len(per_stem) <= 7
        stems.add(len(per_stem))
        for leaves in per_stem:  # base up (a node's leaf follows its subtree in the string)
            assert len(leaves) == 9
            # tmleaf (T) on the first nodes (counter t >= 2, and t = 0 or 1 with p = 0.5),
            # mleaf (L) on the later ones (t < 0).
            assert leaves[0] == "T" and set(leaves[4:]) == {"L"}
            firsts.add(leaves[:4].count("T"))
    assert len(stems) >= 3  # the four extra stems really are random
    assert {2, 3, 4} <= firsts  # both rules at t = 0, 1 are taken


@pytest.mark.parametrize("seed", SEEDS)
def test_mint_stems_have_a_bare_base_before_the_first_node(seed):
    unit = get_species("mint-released").constants["u"]
    for stem in branches(derive("mint-released", seed)):
        first_node = next(i for i, m in enumerate(stem) if m.symbol == "/" and m.params == (130.0,))
        moves = [m.params[0] / unit for m in stem[:first_node] if m.symbol == "F"]
        assert moves[-2:] == pytest.approx([1.0, 0.5])  # their A(t) -> F(1) B(t), B's F(0.5)
