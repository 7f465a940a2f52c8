"""Per-point integer labels: finding them in a PLY, checking them, and voting them per voxel.

A labelled cloud or model carries two int32 arrays: ``label`` (a semantic class, e.g. the
L-System's ``OrganClass``) and ``instance`` (an object id such as a leaf, -1 where none).
Real scans name their class field in many ways; :func:`find_label_fields` picks the first
well-known name present unless the user names one.

Voxel downsampling replaces the points of a voxel by their mean, which cannot be done to a
class id. :func:`voxel_majority` gives each voxel the most frequent value among its points,
ties going to the smallest value: a fixed rule, so the result never depends on point order
or thread count.
"""

from __future__ import annotations

import numpy as np

from plantdreamer.errors import InputError

# Looked for in this order (case-sensitive, as PLY property names are).
LABEL_FIELD_NAMES = (
    "label",
    "labels",
    "class",
    "classification",
    "scalar_Classification",
    "semantic",
    "semantic_label",
    "scalar_label",
    "category",
)
INSTANCE_FIELD_NAMES = (
    "instance",
    "instance_id",
    "instances",
    "leaf_id",
    "scalar_instance",
    "scalar_Instance",
    "object_id",
)
NO_INSTANCE = -1
NO_CLASS = -1  # a point of no class (any other negative id is a class)
# What the per-view masks can hold: 8-bit class values 1..255 and 16-bit instance values
# 1..65535 (0 is background). Other ids are mapped onto these, so these are counts.
MAX_CLASSES = 255
MAX_INSTANCES = 65535
# Vertex properties a cloud reads as position, normal or colour, never as labels.
_GEOMETRY_PROPERTIES = ("x", "y", "z", "nx", "ny", "nz", "red", "green", "blue", "alpha")


def find_label_fields(
    attributes: dict[str, np.ndarray],
    label_field: str | None = None,
    instance_field: str | None = None,
) -> tuple[str | None, str | None]:
    """The attribute names holding labels and instances: the given ones (which must exist),
    else the first well-known name present, else None."""
    names: list[str | None] = []
    for given, known, what in (
        (label_field, LABEL_FIELD_NAMES, "label"),
        (instance_field, INSTANCE_FIELD_NAMES, "instance"),
    ):
        if given is not None:
            if given not in attributes:
                have = ", ".join(attributes) or "none"
                if given in _GEOMETRY_PROPERTIES:
                    raise InputError(
                        f"{what} field {given!r} is the points' position, normal or colour, "
                        f"not an integer property (other properties: {have})"
                    )
                raise InputError(
                    f"{what} field {given!r} is not a vertex property (properties: {have})"
                )
            names.append(given)
        else:
            names.append(next((n for n in known if n in attributes), None))
    return names[0], names[1]


def as_int_labels(name: str, values: np.ndarray) -> np.ndarray:
    """int32 labels from an integer or integer-valued float column; anything else is an
    InputError naming the first offending value."""
    v = np.asarray(values)
    if v.dtype.kind in "iub":
        info = np.iinfo(np.int32)
        if v.size and (int(v.min()) < info.min or int(v.max()) > info.max):
            raise InputError(f"label field {name!r} has values outside the int32 range")
        return v.astype(np.int32)
    if v.dtype.kind != "f":
        raise InputError(f"label field {name!r} has dtype {v.dtype}, not a number")
    bad = ~np.isfinite(v) | (v != np.round(v)) | (np.abs(v) > 2**31 - 1)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise InputError(
            f"label field {name!r} holds non-integer value {float(v[first])!r} (point {first}); "
            "labels must be whole numbers"
        )
    return v.astype(np.int32)


def check_mask_limits(labels: np.ndarray | None) -> None:
    """InputError, before any work, when a model's [N, 2] (class, instance) labels have more
    distinct classes or instances than the per-view masks can tell apart."""
    if labels is None or len(labels) == 0:
        return
    for column, none, limit, what, fix in (
        (0, NO_CLASS, MAX_CLASSES, "classes", "an 8-bit class mask"),
        (1, NO_INSTANCE, MAX_INSTANCES, "instances", "a 16-bit instance mask"),
    ):
        values = np.asarray(labels)[:, column]
        count = np.unique(values[values != none]).size
        if count > limit:
            raise InputError(
                f"{count} distinct {what} do not fit {fix} (at most {limit}); merge some, "
                "or run with --no-labels"
            )


def voxel_keys(points: np.ndarray, voxel_size: float) -> np.ndarray:
    """Each point's voxel, numbered 0..V-1 in (ix, iy, iz) order: the grid and order of
    ``plantdreamer.pointcloud.voxel_downsample`` (origin = min bound - size / 2, index by
    truncation in float64), so voxel k is row k of its output."""
    p = np.asarray(points, dtype=np.float64)
    lo = p.min(axis=0)
    origin = lo - voxel_size * 0.5
    index = ((p - origin) / voxel_size).astype(np.int64)
    bits = [int(top).bit_length() for top in index.max(axis=0)]
    if sum(bits) <= 63:  # one packed key sorts like the (ix, iy, iz) rows, and much faster
        key = (index[:, 0] << (bits[1] + bits[2])) | (index[:, 1] << bits[2]) | index[:, 2]
        _, inverse = np.unique(key, return_inverse=True)
    else:
        _, inverse = np.unique(index, axis=0, return_inverse=True)
    return inverse.reshape(-1)


def voxel_majority(voxel: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Per voxel (ids 0..V-1), the most frequent value among its points; ties go to the
    smallest value."""
    voxel = np.asarray(voxel, dtype=np.int64)
    values = np.asarray(values)
    if voxel.size == 0:
        return values[:0].copy()
    order = np.lexsort((values, voxel))
    v, x = voxel[order], values[order]
    starts = np.flatnonzero(np.r_[True, (v[1:] != v[:-1]) | (x[1:] != x[:-1])])
    counts = np.diff(np.r_[starts, v.size])
    run_voxel, run_value = v[starts], x[starts]
    # Runs are sorted by (voxel, value): the first run of a voxel with its largest count is
    # the smallest value among the most frequent.
    pick = np.lexsort((run_value, -counts, run_voxel))
    first = np.r_[True, run_voxel[pick][1:] != run_voxel[pick][:-1]]
    return run_value[pick][first]


def class_counts(labels: np.ndarray | None) -> dict[str, int]:
    """{class id: number of elements}, for run.json (keys are strings for JSON)."""
    if labels is None:
        return {}
    ids, counts = np.unique(np.asarray(labels), return_counts=True)
    return {str(int(i)): int(c) for i, c in zip(ids, counts, strict=True)}
