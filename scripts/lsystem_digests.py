"""Digests of the L-System meshes: tests/data/lsystem_digests.json, which
tests/test_growth.py holds every species' full-grown plant to (the bytes these seeds gave
before growth stages existed must not change).

    python scripts/lsystem_digests.py > tests/data/lsystem_digests.json

Each plant has ``exact``, SHA-256 of the arrays' bytes (vertices, faces, colours, labels,
instances); ``integers``, SHA-256 of the faces, labels and instances; and ``moments``, the
float64 sums of the vertices, their squares and the colours (7 numbers). A CPU whose numpy
takes other SIMD paths for sin, cos and exp (results differing in the last bit) gives other
``exact`` bytes but the same integers and moments to about 1e-7; ``machine`` names the
numpy version and the CPU features its dispatch found where the file was made.
"""

from __future__ import annotations

import hashlib
import json
import sys

import numpy as np

from plantdreamer.lsystem import PlantMesh, generate_plant, list_species

SEEDS = (0, 1, 2)


def exact_digest(mesh: PlantMesh) -> str:
    h = hashlib.sha256()
    for array in (mesh.vertices, mesh.faces, mesh.colors, mesh.labels, mesh.instances):
        h.update(np.ascontiguousarray(array).tobytes())
    return h.hexdigest()


def integer_digest(mesh: PlantMesh) -> str:
    h = hashlib.sha256()
    for array in (mesh.faces, mesh.labels, mesh.instances):
        h.update(np.ascontiguousarray(array).tobytes())
    return h.hexdigest()


def moments(mesh: PlantMesh) -> list[float]:
    v = mesh.vertices.astype(np.float64)
    c = mesh.colors.astype(np.float64)
    return [*v.sum(axis=0).tolist(), float((v * v).sum()), *c.sum(axis=0).tolist()]


def machine() -> str:
    """numpy's version and the SIMD features its dispatch found on this CPU."""
    from numpy._core._multiarray_umath import __cpu_features__ as features

    found = sorted(name for name, present in features.items() if present)
    return f"numpy {np.__version__}; " + " ".join(found)


def digests(species: list[str] | None = None) -> dict[str, object]:
    plants = {}
    for name in species or list_species():
        for seed in SEEDS:
            mesh = generate_plant(name, seed)
            plants[f"{name}/{seed}"] = {
                "exact": exact_digest(mesh),
                "integers": integer_digest(mesh),
                "moments": moments(mesh),
            }
    return {"machine": machine(), "plants": plants}


if __name__ == "__main__":
    json.dump(digests(sys.argv[1:] or None), sys.stdout, indent=1, sort_keys=True)
    sys.stdout.write("\n")
