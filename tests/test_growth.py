"""Growth stages of the L-System plants: births through the derivation and the turtle, the
full stage the bytes of d0ac9b2 (tests/data/lsystem_digests.json), and a series of 4 stages
of every species: leaf ids persist, insertion points fixed, sizes and counts growing."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from plantdreamer.errors import InputError
from plantdreamer.lsystem import OrganClass, generate_plant, grow, list_species
from plantdreamer.lsystem.engine import LSystem, Rule
from plantdreamer.lsystem.growth import FULL_GROWN
from plantdreamer.lsystem.plant import MIN_LEAF_LENGTH
from plantdreamer.lsystem.turtle import TurtleConfig, interpret

ROOT = Path(__file__).resolve().parents[1]
DIGESTS = json.loads((ROOT / "tests" / "data" / "lsystem_digests.json").read_text())
SERIES = (0.25, 0.5, 0.75, 1.0)

sys.path.insert(0, str(ROOT / "scripts"))
from lsystem_digests import exact_digest, integer_digest, machine, moments  # noqa: E402


def test_births_are_the_steps_that_wrote_each_module():
    rules = [Rule("A(n)", "F(1) [ L(n) ] A(n+1)"), Rule("L(x)", "L(x*rand(1, 2))")]
    system = LSystem("F(2) A(0)", rules)
    string, births = system.derive_timed(3, np.random.default_rng(5))
    # The same string and random draws as derive.
    assert string == system.derive(3, np.random.default_rng(5))
    by_symbol = [(m.symbol, b) for m, b in zip(string, births, strict=True)]
    assert [b for s, b in by_symbol if s == "F"] == [0, 1, 2, 3]
    assert by_symbol[-1] == ("A", 3)
    # A leaf rewritten in place (L -> L) is born again at every step that rewrites it.
    assert [b for s, b in by_symbol if s == "L"] == [3, 3, 3]


def test_the_turtle_keeps_each_stem_point_and_organ_birth():
    system = LSystem("F(0.02) A", [Rule("A", "F(0.03) [ +(30) L(0.05) ] A")])
    string, births = system.derive_timed(2, np.random.default_rng(0))
    skeleton = interpret(string, TurtleConfig(max_step=0.01), births)
    (chain,) = skeleton.chains
    # F(0.02) in 2 steps (born 0), then F(0.03) in 3 steps per node (born 1, then 2).
    assert chain.births.tolist() == [0, 0, 0, 1, 1, 1, 2, 2, 2]
    assert [o.birth for o in skeleton.organs] == [1, 2]
    # Without births, every module is born at 0 (the skeleton is otherwise the same).
    plain = interpret(string, TurtleConfig(max_step=0.01))
    assert plain.chains[0].births.tolist() == [0] * 9
    np.testing.assert_array_equal(plain.chains[0].points, chain.points)


@pytest.mark.parametrize("species", list_species())
def test_the_full_stage_is_the_plant_of_d0ac9b2(species):
    same_machine = DIGESTS["machine"] == machine()
    for seed in range(3):
        mesh = generate_plant(species, seed)
        if seed == 0:  # given the full stage: the plant made without a stage
            assert exact_digest(generate_plant(species, seed, FULL_GROWN)) == exact_digest(mesh)
        recorded = DIGESTS["plants"][f"{species}/{seed}"]
        assert integer_digest(mesh) == recorded["integers"]
        np.testing.assert_allclose(moments(mesh), recorded["moments"], rtol=1e-7)
        if same_machine:  # numpy's SIMD paths for sin/cos/exp decide the last bits
            assert exact_digest(mesh) == recorded["exact"]


def leaf_figures(mesh):
    """Per leaf instance (by id): area (numpy over the faces), base vertex, mean colour."""
    areas, _ = mesh.face_areas_normals()
    faces = mesh.faces[mesh.labels[mesh.faces[:, 0]] == OrganClass.LEAF]
    leaf_areas = areas[mesh.labels[mesh.faces[:, 0]] == OrganClass.LEAF]
    ids = mesh.instances[faces[:, 0]]
    per_leaf = np.bincount(ids, weights=leaf_areas)
    # A blade's vertices are consecutive, its first the base tip (organs.build_blades).
    starts = np.flatnonzero(np.r_[True, np.diff(mesh.instances) != 0])
    ends = np.r_[starts[1:], len(mesh.instances)]
    span = {int(mesh.instances[a]): (a, b) for a, b in zip(starts, ends, strict=True)}
    return {
        int(i): (float(per_leaf[i]), mesh.vertices[span[i][0]], mesh.colors[slice(*span[i])])
        for i in np.unique(ids)
    }


@pytest.mark.parametrize("species", list_species())
def test_a_series_keeps_leaf_ids_insertions_and_grows(species):
    plants = [grow(species, 0, g) for g in SERIES]
    full = plants[-1]
    full_figures = leaf_figures(full.mesh)
    previous: dict = {}
    counts = []
    for plant in plants:
        figures = leaf_figures(plant.mesh)
        counts.append(len(figures))
        assert [b.instance for b in plant.blades] == sorted(figures)
        assert set(previous) <= set(figures), "a leaf went missing"
        for i, (area, base, colors) in figures.items():
            # The leaf is the full-grown plant's leaf i, at its insertion point.
            np.testing.assert_array_equal(base, full.leaves[i].position.astype(np.float32))
            assert base.tolist() == full_figures[i][1].tolist()
            if i in previous:
                assert area >= previous[i][0], f"leaf {i} shrank"
                np.testing.assert_array_equal(colors, previous[i][2])  # the same draws
        previous = figures
    assert counts == sorted(counts)
    assert counts[-1] == full.mesh.n_leaves == len(full.leaves)
    assert counts[0] < counts[-1]
    # Stems grow too: never a stem vertex above the full plant's height.
    tops = [p.mesh.vertices[p.mesh.labels == OrganClass.STEM, 2].max() for p in plants if
            (p.mesh.labels == OrganClass.STEM).any()]  # fmt: skip
    assert tops == sorted(tops)


def test_a_leaf_emerges_at_its_recorded_stage():
    plant = grow("kale", 1)
    stage = plant.stage
    for blade in plant.blades[2:6]:
        organ = blade.organ
        emerged = stage.emerged(organ.birth, organ.params[0], MIN_LEAF_LENGTH)
        assert 0 < emerged <= 1
        after = {b.instance for b in grow("kale", 1, min(1.0, emerged + 1e-6)).blades}
        before = {b.instance for b in grow("kale", 1, emerged - 1e-3).blades}
        assert blade.instance in after and blade.instance not in before


@pytest.mark.parametrize("growth", [0, -0.5, 1.5, math.nan, math.inf, True, "0.5", None])
def test_a_stage_outside_its_range_is_refused(growth):
    with pytest.raises(InputError, match=r"growth must be a stage in \(0, 1\]"):
        grow("bean", 0, growth)


def test_the_settings_full_stage_is_the_lsystems():
    from plantdreamer.pipeline import GenerateConfig
    from plantdreamer.pipeline.model.source import FULL_GROWN as SETTINGS_FULL_GROWN

    assert SETTINGS_FULL_GROWN == FULL_GROWN == GenerateConfig().source.growth


def test_plants_made_before_traits_keep_their_config_hash():
    """A dataset's plant at the full stage, with its leaves' occlusion, hashes as at
    d0ac9b2 (its manifest still matches: no rerun); another stage is another plant."""
    from plantdreamer.dataset.plant import config_hash
    from plantdreamer.pipeline import GenerateConfig

    settings = dict(species="bean", steps=20, points=2000)
    # The hash d0ac9b2's config_hash gave this config (no growth or traits settings then).
    assert config_hash(GenerateConfig.of(**settings)) == "fe63f5aaa6d5247a"
    for other in ({"growth": 0.5}, {"leaf_occlusion": False}):
        assert config_hash(GenerateConfig.of(**settings, **other)) != "fe63f5aaa6d5247a"
