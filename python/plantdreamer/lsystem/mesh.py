"""``PlantMesh``: a labelled triangle mesh of a plant in its pot, and how parts are joined."""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import TYPE_CHECKING

import numpy as np

from plantdreamer.errors import InputError

if TYPE_CHECKING:
    import trimesh


class OrganClass(IntEnum):
    """Per-vertex organ label of a ``PlantMesh`` (and of the point clouds sampled from it).

    LEAF: leaf blades (each leaflet of a compound leaf is its own leaf instance).
    STEM: stems, branches, petioles and rachises (tubes).
    POT: the pot, inside and outside.
    SOIL: the soil surface (the disc at z = 0 inside the pot).
    """

    LEAF = 1
    STEM = 2
    POT = 3
    SOIL = 4


@dataclass
class PlantMesh:
    """A plant mesh in metres, z up, soil surface at z = 0, pot centred on x = y = 0.

    vertices: float32 [V, 3].
    faces: int64 [F, 3]; counter-clockwise seen from the outside (normals point out of stems
        and pot, up out of the soil, and out of each leaf blade's upper (adaxial) side).
    colors: float32 [V, 3] in [0, 1].
    labels: int32 [V], an ``OrganClass`` value per vertex (a face's three vertices share it).
    instances: int32 [V], the leaf instance id (0, 1, ...) of leaf vertices, -1 elsewhere.
    """

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray
    labels: np.ndarray
    instances: np.ndarray

    def __post_init__(self) -> None:
        v = len(self.vertices)
        checks = {
            "vertices": (self.vertices, (v, 3)),
            "colors": (self.colors, (v, 3)),
            "labels": (self.labels, (v,)),
            "instances": (self.instances, (v,)),
        }
        for name, (array, shape) in checks.items():
            if not isinstance(array, np.ndarray) or array.shape != shape:
                raise InputError(f"PlantMesh.{name} must have shape {list(shape)}")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3:
            raise InputError("PlantMesh.faces must have shape [F, 3]")
        if len(self.faces) and (self.faces.min() < 0 or self.faces.max() >= v):
            raise InputError("PlantMesh.faces index a vertex that does not exist")

    @property
    def n_leaves(self) -> int:
        """Number of leaf instances (at an earlier growth stage the ids have gaps: those
        of the full-grown plant's leaves not there yet)."""
        return len(np.unique(self.instances[self.instances >= 0]))

    def face_areas_normals(self) -> tuple[np.ndarray, np.ndarray]:
        """Face areas (float64 [F]) and unit face normals (float64 [F, 3]), from the winding."""
        tri = self.vertices.astype(np.float64)[self.faces]
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        double = np.linalg.norm(cross, axis=1)
        normals = cross / np.maximum(double, 1e-300)[:, None]
        return 0.5 * double, normals

    def boundary_distance(self) -> np.ndarray:
        """Each vertex's distance (float64 [V]) to the nearest boundary edge (an edge of one
        face only: a leaf's outline, a tube's open end) of its own part (vertices of the same
        label and instance); inf for a part without boundary (a closed surface)."""
        edges = np.sort(self.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        unique, count = np.unique(edges, axis=0, return_counts=True)
        boundary = unique[count == 1]
        vertices = self.vertices.astype(np.float64)
        part = np.unique(
            np.stack([self.labels, self.instances], axis=1), axis=0, return_inverse=True
        )[1]
        part = part.reshape(-1)
        out = np.full(len(vertices), np.inf)
        for k in np.unique(part[boundary[:, 0]]):
            a = vertices[boundary[part[boundary[:, 0]] == k, 0]]
            ab = vertices[boundary[part[boundary[:, 0]] == k, 1]] - a
            ab_len2 = np.maximum((ab * ab).sum(axis=1), 1e-300)
            for chunk in np.array_split(
                np.flatnonzero(part == k), max(1, (part == k).sum() // 512)
            ):
                ap = vertices[chunk, None, :] - a[None]  # [c, E, 3]
                t = np.clip((ap * ab[None]).sum(axis=2) / ab_len2, 0.0, 1.0)
                d = ap - t[..., None] * ab[None]
                out[chunk] = np.sqrt((d * d).sum(axis=2).min(axis=1))
        return out

    def to_trimesh(self) -> trimesh.Trimesh:
        """A ``trimesh.Trimesh`` with vertex colours (RGBA uint8); nothing is merged or reordered.

        The organ labels and leaf instances ride along as ``vertex_attributes`` ``label`` and
        ``instance``, stored as float32 holding exact integers: glTF vertex attributes must be
        4-byte aligned and has no int32 type, and trimesh's glTF writer mishandles narrower
        integers. trimesh writes them as PLY vertex properties and as glTF attributes
        ``_label`` and ``_instance``.
        """

        import trimesh

        rgba = np.empty((len(self.colors), 4), dtype=np.uint8)
        rgba[:, :3] = np.round(np.clip(self.colors, 0.0, 1.0) * 255.0)
        rgba[:, 3] = 255
        mesh = trimesh.Trimesh(
            vertices=self.vertices, faces=self.faces, vertex_colors=rgba, process=False
        )
        mesh.vertex_attributes["label"] = self.labels.astype(np.float32)
        mesh.vertex_attributes["instance"] = self.instances.astype(np.float32)
        return mesh


class MeshAccumulator:
    """Collects parts (vertices, faces, colours, label, instance) and joins them in order."""

    def __init__(self) -> None:
        self._parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self._count = 0

    def add(
        self,
        vertices: np.ndarray,
        faces: np.ndarray,
        colors: np.ndarray,
        label: OrganClass,
        instances: np.ndarray | int = -1,
    ) -> None:
        n = len(vertices)
        inst = np.broadcast_to(np.asarray(instances, dtype=np.int32), (n,))
        lab = np.full(n, int(label), dtype=np.int32)
        self._parts.append((vertices, faces + self._count, colors, lab, inst))
        self._count += n

    def build(self) -> PlantMesh:
        if not self._parts:
            raise InputError("the plant has no geometry")
        v, f, c, lab, inst = (np.concatenate(x) for x in zip(*self._parts, strict=True))
        return PlantMesh(
            vertices=v.astype(np.float32),
            faces=f.astype(np.int64),
            colors=np.clip(c, 0.0, 1.0).astype(np.float32),
            labels=lab.astype(np.int32),
            instances=inst.astype(np.int32),
        )
