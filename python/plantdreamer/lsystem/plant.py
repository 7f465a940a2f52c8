"""From a species and a seed to a labelled mesh: derive, interpret, build surfaces; at an
earlier growth stage, the same plant younger (``growth.py``)."""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field

import numpy as np

from plantdreamer.errors import InputError
from plantdreamer.lsystem.geometry import tube
from plantdreamer.lsystem.growth import FULL_GROWN, Stage, check_growth
from plantdreamer.lsystem.mesh import MeshAccumulator, OrganClass, PlantMesh
from plantdreamer.lsystem.organs import LeafBatch, build_blades, build_pot, build_soil
from plantdreamer.lsystem.species import get_species
from plantdreamer.lsystem.species.base import Species
from plantdreamer.lsystem.turtle import Organ, Skeleton, interpret

# Leaf modules shorter than this (metres) are not built: sub-millimetre blades are invisible
# and their triangles would be slivers.
MIN_LEAF_LENGTH = 1e-3


@dataclass(frozen=True)
class Blade:
    """A leaf blade in the mesh: its instance id, organ (insertion frame), grid of surface
    points (float64 [rows, cols, 3], metres: rows along the midrib from base to tip, the
    middle column the midrib; ``organs.build_blades``) and the scale of its size against the
    full-grown leaf's (1 at the full stage)."""

    instance: int
    organ: Organ
    grid: np.ndarray
    scale: float

    @property
    def midrib(self) -> np.ndarray:
        """[rows, 3]: the mesh's midrib from the blade's base to its tip (the mesh makes
        each end row one vertex: the midrib's at the base, the first column's at the tip,
        which a ruffled margin lifts off the midrib's end)."""
        return np.vstack([self.grid[:-1, self.grid.shape[1] // 2], self.grid[-1, :1]])

    @property
    def rows(self) -> np.ndarray:
        """[rows - 2, cols, 3]: the rows across the blade that the mesh keeps (not the
        two end rows, which it makes one vertex each)."""
        return self.grid[1:-1]


@dataclass
class GrownPlant:
    """A plant before and after meshing: its skeleton at its stage (stems drawn so far,
    organs born so far), the full-grown plant's leaves in instance order (leaf instance i of
    the mesh, at any stage, is ``leaves[i]``), the blades in the mesh, the mesh, and the
    stage it was grown to."""

    species: Species
    skeleton: Skeleton
    leaves: list[Organ]  # leaves[i] is leaf instance i of the mesh
    mesh: PlantMesh
    blades: list[Blade] = field(default_factory=list)  # ascending instance
    stage: Stage = field(default_factory=lambda: Stage(FULL_GROWN, 1))


def _streams(seed: int) -> tuple[np.random.Generator, np.random.Generator]:
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    grammar, shapes = np.random.SeedSequence(int(seed)).spawn(2)
    return np.random.default_rng(grammar), np.random.default_rng(shapes)


def grow(species: str, seed: int, growth: float = FULL_GROWN) -> GrownPlant:
    """Grows ``species`` from ``seed`` to the stage ``growth`` (in (0, 1]: the fraction of
    the species' derivation steps; ``growth.py``) and keeps the skeleton and blades (for
    traits, tests, tools). The full stage is the plant ``generate_plant`` has always made."""
    spec = get_species(species)
    check_growth(growth)
    rng_grammar, rng_shapes = _streams(seed)
    modules, births = spec.lsystem.derive_timed(spec.iterations, rng_grammar)
    skeleton = interpret(modules, spec.turtle, births)
    stage = Stage(float(growth), spec.iterations)
    return _build(spec, skeleton, stage, rng_shapes)


def generate_plant(species: str, seed: int, growth: float = FULL_GROWN) -> PlantMesh:
    """A potted plant of ``species`` (see ``list_species()``), fully determined by ``seed``
    (and ``growth``, its stage: 1 is full-grown).

    Metres, z up, soil surface at z = 0, pot centred on x = y = 0. Raises InputError for an
    unknown species, a negative seed or a stage outside (0, 1].
    """
    return grow(species, seed, growth).mesh


def _build(spec: Species, skeleton: Skeleton, stage: Stage, rng: np.random.Generator) -> GrownPlant:
    """The mesh at ``stage``. Every random draw is the full-grown plant's, in its order
    and sizes (stems and leaves not yet there are drawn for and left out), so a part looks
    the same at every stage it exists at and the full stage is the same bytes as ever."""
    parts = MeshAccumulator()
    soil_vertices, soil_faces, soil_colors = build_soil(spec.pot, rng)
    parts.add(soil_vertices, soil_faces, soil_colors, OrganClass.SOIL)
    pot_vertices, pot_faces, pot_colors = build_pot(spec.pot, rng)
    parts.add(pot_vertices, pot_faces, pot_colors, OrganClass.POT)

    stem_color = np.asarray(spec.stem_color)
    base_color = np.asarray(spec.stem_base_color or spec.stem_color)
    staged = stage.skeleton(skeleton)
    for chain, now in zip(skeleton.chains, staged.chains, strict=True):
        if np.ptp(chain.points, axis=0).max() <= 1e-6:
            continue  # a stem of sub-micrometre moves only: nothing to see
        vertices, faces = tube(chain.points, chain.radii, spec.stem_sides)
        full_size, drawn = len(vertices), True
        if now is not chain:  # an earlier stage: the stem as far as it is drawn
            drawn = len(now.points) >= 2 and np.ptp(now.points, axis=0).max() > 1e-6
            if drawn:
                vertices, faces = tube(now.points, now.radii, spec.stem_sides)
        # Colour from the base colour near the soil to the stem colour higher up (the
        # noise drawn for the full-grown stem's vertices).
        t = np.clip(vertices[:, 2:3] / 0.06, 0.0, 1.0)
        color = base_color + t * (stem_color - base_color)
        tint = rng.uniform(0.92, 1.08)
        noise = rng.standard_normal((full_size, 1))
        if drawn:
            color = color * tint * (1 + 0.03 * noise[: len(vertices)])
            parts.add(vertices, faces, color, OrganClass.STEM)

    floor = spec.pot.rim_top + 0.003
    leaves: list[Organ] = []
    blades: list[Blade] = []
    for symbol, shape in spec.leaves.items():
        organs = [
            o
            for o in skeleton.organs
            if o.symbol == symbol and o.params and o.params[0] >= MIN_LEAF_LENGTH
        ]
        if not organs:
            continue
        scales = np.array([stage.scale(o.birth) for o in organs])
        lengths = np.array([o.params[0] for o in organs]) * scales
        batch = LeafBatch(
            positions=np.array([o.position for o in organs]),
            headings=np.array([o.heading for o in organs]),
            lefts=np.array([o.left for o in organs]),
            ups=np.array([o.up for o in organs]),
            lengths=lengths,
            tones=np.array(
                [np.clip(o.params[1], 0, 1) if len(o.params) > 1 else 0.0 for o in organs]
            ),
        )
        grids, vertices, faces, colors = build_blades(shape, batch, rng, floor)
        for k, organ in enumerate(organs):
            instance = len(leaves) + k
            if stage.has(organ.birth) and lengths[k] >= MIN_LEAF_LENGTH:
                parts.add(vertices[k], faces, colors[k], OrganClass.LEAF, instance)
                blades.append(Blade(instance, organ, grids[k], float(scales[k])))
        leaves.extend(organs)
    return GrownPlant(spec, staged, leaves, parts.build(), blades, stage)
