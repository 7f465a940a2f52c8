"""3D labels as point-cloud tools read them: class names in PLY header comments, and
``points.ply``, one coloured, labelled point per Gaussian of ``plant.ply``.

``plant.ply`` keeps the INRIA layout, whose zero normals and SH colour coefficients mean
nothing to a point-cloud reader (Open3D's ``read_point_cloud`` finds no colour in it).
``points.ply`` has ``x y z`` (float), ``red green blue`` (uchar: the Gaussians' view-independent
colour, ``0.5 + C0 * f_dc`` clipped) and ``label instance`` (int32), row i being Gaussian i of
``plant.ply``; Open3D's legacy reader gets points and colours, its tensor reader the labels
too, and nerfstudio's splatfacto starts from it through ``ply_file_path``. Both files name
their classes with one header comment each, ``class <id> <name>``; label ids are the
same numbers as the class map pixels of ``labels/`` (0 stays background there).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from plantdreamer.errors import PlyError

SH_C0 = 0.28209479177387814  # the degree-0 spherical harmonic
_CLASS_COMMENT = re.compile(r"^class (-?\d+) (.+)$")
_HEADER_LIMIT = 1 << 16  # bytes searched for end_header


def class_comments(names: dict[int, str] | None) -> tuple[str, ...]:
    """Header comments naming each class, ASCII (as PLY readers require)."""
    if not names:
        return ()
    return tuple(
        f"class {c} " + " ".join(name.encode("ascii", "replace").decode().split())
        for c, name in sorted(names.items())
    )


def read_comments(path: Path) -> list[str]:
    """The comments of a PLY header, without the ``comment`` keyword."""
    with open(path, "rb") as f:
        head = f.read(_HEADER_LIMIT)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        raise PlyError(f"{path}: not a PLY file (no header)")
    lines = head[:end].decode("ascii", "replace").splitlines()
    return [line.strip()[len("comment ") :] for line in lines if line.startswith("comment ")]


def read_class_names(path: Path) -> dict[int, str]:
    """The ``class <id> <name>`` comments of a PLY header ({} when there are none)."""
    names = {}
    for comment in read_comments(path):
        m = _CLASS_COMMENT.match(comment)
        if m:
            names[int(m.group(1))] = m.group(2)
    return names


def write_points_ply(plant_ply: Path, out: Path) -> int:
    """Writes ``points.ply`` from a 3DGS PLY; returns the number of points."""
    from plantdreamer.cloud import PointCloud
    from plantdreamer.io import read_splat_ply, write_ply

    g = read_splat_ply(plant_ply)
    colors = np.clip(0.5 + SH_C0 * g.sh[:, 0, :], 0.0, 1.0).astype(np.float32)
    attributes = {}
    if g.labels is not None:
        attributes = {"label": g.labels[:, 0].copy(), "instance": g.labels[:, 1].copy()}
    cloud = PointCloud(g.means.copy(), colors=colors, attributes=attributes)
    write_ply(out, cloud, comments=read_comments(plant_ply))  # class names, export offset
    return len(g)
