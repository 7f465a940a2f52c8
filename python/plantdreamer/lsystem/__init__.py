"""Procedural potted plants from stochastic parametric L-Systems (no Blender).

    >>> from plantdreamer.lsystem import generate_plant, sample_points
    >>> mesh = generate_plant("bean", seed=3)         # PlantMesh, metres, z up
    >>> cloud = sample_points(mesh, n=100_000, seed=0)  # PointCloud with labels

``list_species()`` names the species; ``OrganClass`` documents the per-vertex labels.
"""

from __future__ import annotations

from plantdreamer.lsystem.mesh import OrganClass, PlantMesh
from plantdreamer.lsystem.plant import GrownPlant, generate_plant, grow
from plantdreamer.lsystem.sampling import sample_points
from plantdreamer.lsystem.species import list_species, register

__all__ = [
    "GrownPlant",
    "OrganClass",
    "PlantMesh",
    "generate_plant",
    "grow",
    "list_species",
    "register",
    "sample_points",
]
