"""The traits of an L-System plant from its exact geometry: the mesh (areas, normals, the
plant's outline) and the skeleton (stems, each leaf's insertion and midrib), in the
plant's frame: metres, z up, the soil surface at z = 0, the pot centred on x = y = 0.

What a species' mesh and skeleton provide is all that is read, so any registered species
(a user's own too) gets its traits without a line of its own (docs/traits.md).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from plantdreamer.lsystem.mesh import OrganClass, PlantMesh
from plantdreamer.lsystem.plant import MIN_LEAF_LENGTH, Blade, GrownPlant
from plantdreamer.lsystem.turtle import Organ, Skeleton
from plantdreamer.traits.shapes import (
    azimuth_deg,
    canopy,
    extent,
    inclination_deg,
    polyline_length,
)

PLANT_ORGANS = (OrganClass.LEAF, OrganClass.STEM)  # what the plant's size is measured on
# Where each figure comes from: the mesh's faces and vertices, or the skeleton.
PLANT_SOURCES = {
    "leaf_count": "mesh",
    "leaf_area": "mesh",
    "height": "mesh",
    "canopy_width": "mesh",
    "canopy_hull_area": "mesh",
    "stem_count": "skeleton",
}
LEAF_SOURCES = {
    "area": "mesh",
    "centroid": "mesh",
    "extent": "mesh",
    "inclination": "mesh",
    "length": "skeleton",
    "width": "skeleton",
    "azimuth": "skeleton",
    "base": "skeleton",
    "node": "skeleton",
    "stem": "skeleton",
    "shoot": "skeleton",
    "emerged": "skeleton",
}


def plant_traits(plant: GrownPlant, since: float | None = None) -> dict[str, Any]:
    """The ``plant`` and ``leaves`` records of ``plant`` (``since``: an earlier growth
    stage; leaves that emerged after it are marked ``new``)."""
    mesh, stage = plant.mesh, plant.stage
    areas, normals = mesh.face_areas_normals()
    face_label = mesh.labels[mesh.faces[:, 0]]
    face_instance = mesh.instances[mesh.faces[:, 0]]
    organs = np.isin(mesh.labels, [int(c) for c in PLANT_ORGANS])
    body = mesh.vertices[organs].astype(np.float64)
    width, hull_area = canopy(body)
    leaves = [
        _leaf(blade, mesh, areas, normals, face_instance == blade.instance, plant, since)
        for blade in plant.blades
    ]
    leaf_faces = face_label == OrganClass.LEAF
    return {
        "plant": {
            "species": plant.species.name,
            "growth": {"stage": stage.growth, "steps": stage.steps, "since": since},
            "leaf_count": len(leaves),
            "leaf_area": float(areas[leaf_faces].sum()),
            "height": float(body[:, 2].max()) if len(body) else 0.0,
            "canopy_width": width,
            "canopy_hull_area": hull_area,
            "stem_count": stem_count(plant.skeleton),
            "sources": PLANT_SOURCES,
        },
        "leaves": leaves,
    }


def _leaf(
    blade: Blade,
    mesh: PlantMesh,
    areas: np.ndarray,
    normals: np.ndarray,
    faces: np.ndarray,
    plant: GrownPlant,
    since: float | None,
) -> dict[str, Any]:
    organ = blade.organ
    weights = areas[faces]
    corners = mesh.vertices[mesh.faces[faces]].astype(np.float64)  # [f, 3, 3]
    centroid = (corners.mean(axis=1) * weights[:, None]).sum(axis=0) / weights.sum()
    mean_normal = (normals[faces] * weights[:, None]).sum(axis=0)
    vertices = mesh.vertices[mesh.instances == blade.instance]
    stem, node = insertion(organ, plant.skeleton)
    midrib = blade.midrib
    emerged = plant.stage.emerged(organ.birth, organ.params[0], MIN_LEAF_LENGTH)
    record = {
        "instance": blade.instance,
        "area": float(weights.sum()),
        "length": polyline_length(midrib),
        "width": max(polyline_length(row) for row in blade.rows),
        "inclination": inclination_deg(mean_normal),
        "azimuth": azimuth_deg(midrib[-1] - midrib[0]),
        "base": [float(v) for v in organ.position],
        "base_height": float(organ.position[2]),
        "node": [float(v) for v in node],
        "node_height": float(node[2]),
        "stem": stem,
        "shoot": shoot_of(stem, plant.skeleton),
        "centroid": centroid.tolist(),
        "extent": extent(vertices),
        "emerged": emerged,
    }
    if since is not None:
        record["new"] = emerged > since
    return record


def insertion(organ: Organ, skeleton: Skeleton) -> tuple[int, np.ndarray]:
    """A leaf's parent stem (a chain index, -1: none) and node: where its stalk leaves
    that stem. The stalk is the chain the leaf grows from when that chain branches off
    another and bears no chain itself (a petiole, with its rachis); otherwise the leaf
    sits on its stem, at its base."""
    chains, c = skeleton.chains, organ.chain
    if c >= 0 and chains[c].parent >= 0 and len(chains[c].points):
        bears = any(chain.parent == c and len(chain.points) for chain in chains)
        if not bears:
            return chains[c].parent, np.asarray(chains[c].points[0], dtype=np.float64)
    return c, np.asarray(organ.position, dtype=np.float64)


def shoot_of(chain: int, skeleton: Skeleton) -> int:
    """The shoot (its index among ``shoots``) a chain belongs to: the stem from the soil
    its parents lead down to (-1: none)."""
    if chain < 0:
        return -1
    while skeleton.chains[chain].parent >= 0:
        chain = skeleton.chains[chain].parent
    roots = shoots(skeleton)
    return roots.index(chain) if chain in roots else -1


def shoots(skeleton: Skeleton) -> list[int]:
    """The chains drawn at this stage that grow from no other (the plant's stems from the
    soil), in turtle order."""
    return [
        i
        for i, chain in enumerate(skeleton.chains)
        if chain.parent < 0 and len(chain.points) >= 2 and np.ptp(chain.points, axis=0).max() > 1e-6
    ]


def stem_count(skeleton: Skeleton) -> int:
    """The plant's stems from the soil (mint's shoots; 1 for a bean)."""
    return len(shoots(skeleton))
