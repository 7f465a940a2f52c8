"""From a species and a seed to a labelled mesh: derive, interpret, build surfaces."""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np

from plantdreamer.errors import InputError
from plantdreamer.lsystem.geometry import tube
from plantdreamer.lsystem.mesh import MeshAccumulator, OrganClass, PlantMesh
from plantdreamer.lsystem.organs import LeafBatch, build_leaves, build_pot, build_soil
from plantdreamer.lsystem.species import get_species
from plantdreamer.lsystem.species.base import Species
from plantdreamer.lsystem.turtle import Organ, Skeleton, interpret

# Leaf modules shorter than this (metres) are not built: sub-millimetre blades are invisible
# and their triangles would be slivers.
MIN_LEAF_LENGTH = 1e-3


@dataclass
class GrownPlant:
    """A plant before and after meshing: its skeleton, its leaves in instance order, the mesh."""

    species: Species
    skeleton: Skeleton
    leaves: list[Organ]  # leaves[i] is leaf instance i of the mesh
    mesh: PlantMesh


def _streams(seed: int) -> tuple[np.random.Generator, np.random.Generator]:
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    grammar, shapes = np.random.SeedSequence(int(seed)).spawn(2)
    return np.random.default_rng(grammar), np.random.default_rng(shapes)


def grow(species: str, seed: int) -> GrownPlant:
    """Grows ``species`` from ``seed`` and keeps the intermediate skeleton (for tests, tools)."""
    spec = get_species(species)
    rng_grammar, rng_shapes = _streams(seed)
    modules = spec.lsystem.derive(spec.iterations, rng_grammar)
    skeleton = interpret(modules, spec.turtle)
    mesh, leaves = _build_mesh(spec, skeleton, rng_shapes)
    return GrownPlant(spec, skeleton, leaves, mesh)


def generate_plant(species: str, seed: int) -> PlantMesh:
    """A potted plant of ``species`` (see ``list_species()``), fully determined by ``seed``.

    Metres, z up, soil surface at z = 0, pot centred on x = y = 0. Raises InputError for an
    unknown species or a negative seed.
    """
    return grow(species, seed).mesh


def _build_mesh(
    spec: Species, skeleton: Skeleton, rng: np.random.Generator
) -> tuple[PlantMesh, list[Organ]]:
    parts = MeshAccumulator()
    soil_vertices, soil_faces, soil_colors = build_soil(spec.pot, rng)
    parts.add(soil_vertices, soil_faces, soil_colors, OrganClass.SOIL)
    pot_vertices, pot_faces, pot_colors = build_pot(spec.pot, rng)
    parts.add(pot_vertices, pot_faces, pot_colors, OrganClass.POT)

    stem_color = np.asarray(spec.stem_color)
    base_color = np.asarray(spec.stem_base_color or spec.stem_color)
    for chain in skeleton.chains:
        if np.ptp(chain.points, axis=0).max() <= 1e-6:
            continue  # a stem of sub-micrometre moves only: nothing to see
        vertices, faces = tube(chain.points, chain.radii, spec.stem_sides)
        # Colour from the base colour near the soil to the stem colour higher up.
        t = np.clip(vertices[:, 2:3] / 0.06, 0.0, 1.0)
        color = base_color + t * (stem_color - base_color)
        color = color * rng.uniform(0.92, 1.08) * (1 + 0.03 * rng.standard_normal((len(t), 1)))
        parts.add(vertices, faces, color, OrganClass.STEM)

    floor = spec.pot.rim_top + 0.003
    leaves: list[Organ] = []
    for symbol, shape in spec.leaves.items():
        organs = [
            o
            for o in skeleton.organs
            if o.symbol == symbol and o.params and o.params[0] >= MIN_LEAF_LENGTH
        ]
        if not organs:
            continue
        batch = LeafBatch(
            positions=np.array([o.position for o in organs]),
            headings=np.array([o.heading for o in organs]),
            lefts=np.array([o.left for o in organs]),
            ups=np.array([o.up for o in organs]),
            lengths=np.array([o.params[0] for o in organs]),
            tones=np.array(
                [np.clip(o.params[1], 0, 1) if len(o.params) > 1 else 0.0 for o in organs]
            ),
        )
        vertices, faces, colors = build_leaves(shape, batch, rng, floor)
        for k in range(len(organs)):
            parts.add(vertices[k], faces, colors[k], OrganClass.LEAF, len(leaves) + k)
        leaves.extend(organs)
    return parts.build(), leaves
