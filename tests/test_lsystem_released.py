"""The authors' released L-System structures: node and leaf counts over seeds."""

import numpy as np
import pytest

from plantdreamer.lsystem import grow, list_species
from plantdreamer.lsystem.plant import _streams
from plantdreamer.lsystem.species import get_species

SEEDS = range(8)


def derive(name, seed):
    """The derived string ``grow`` interprets for this seed (the same grammar stream)."""
    spec = get_species(name)
    return spec.lsystem.derive(spec.iterations, _streams(seed)[0])


def count(modules, symbol, param=None):
    return sum(m.symbol == symbol and (param is None or m.params[0] == param) for m in modules)


def test_released_variants_are_registered_beside_ours():
    assert {"bean-released", "mint-released", "kale-released"} <= set(list_species())


@pytest.mark.parametrize("seed", SEEDS)
def test_bean_has_6_petiole_nodes_with_leaf_pairs_and_3_apex_leaves(seed):
    plant = grow("bean-released", seed)
    symbols = [o.symbol for o in plant.leaves]
    assert symbols.count("L") == 12 and symbols.count("S") == 3
    assert count(derive("bean-released", seed), "&", 70.0) == 6  # one 70-degree petiole a node
    # The two leaves of a pair sit at the same petiole tip.
    pairs = np.array([o.position for o in plant.leaves if o.symbol == "L"]).reshape(6, 2, 3)
    np.testing.assert_allclose(pairs[:, 0], pairs[:, 1], atol=1e-9)


def test_mint_has_3_to_7_zigzag_stems_with_one_leaf_per_node():
    stems = set()
    for seed in range(20):
        plant = grow("mint-released", seed)
        modules = derive("mint-released", seed)
        nodes = count(modules, "/", 130.0)
        assert len(plant.leaves) == nodes  # one alternate leaf per node
        assert nodes % 9 == 0 and 3 <= nodes // 9 <= 7
        stems.add(nodes // 9)
    assert len(stems) >= 3  # the four extra stems really are random


@pytest.mark.parametrize("seed", SEEDS)
def test_kale_rises_one_unit_per_leaf_with_level_leaves_of_one_size(seed):
    plant = grow("kale-released", seed)
    assert len(plant.leaves) == 5 == count(derive("kale-released", seed), "$")
    assert len({o.params[0] for o in plant.leaves}) == 1  # one size
    headings = np.array([o.heading for o in plant.leaves])
    assert np.all(np.abs(headings[:, 2]) < np.sin(np.radians(25)))  # near horizontal
    heights = np.sort([o.position[2] for o in plant.leaves])
    np.testing.assert_allclose(np.diff(heights), 0.02, atol=0.004)  # 1 unit = 0.02 m
