"""Reading and writing PLY files: point clouds and 3DGS models (INRIA layout).

The native core (``crates/splat_core/src/ply``) decodes the ``vertex`` element of ascii,
binary little endian and binary big endian files into named, typed columns; this module
decides what they mean.

Point clouds (:func:`read_ply`, :func:`write_ply`):

- ``positions`` come from ``x, y, z``: float32 [N, 3], or float64 when the file stores any
  of them as ``double`` (nothing is lost). Integer coordinates become float32.
- ``colors`` come from ``red, green, blue`` (or ``diffuse_red`` ..., or ``r, g, b``):
  uchar is divided by 255, ushort by 65535, float/double are taken as stored (0-1 by
  convention) -- always float32 [N, 3]. Colours of other integer types are not
  interpreted and stay in ``attributes``. ``alpha`` stays in ``attributes`` too, so it
  round-trips.
- ``normals`` come from ``nx, ny, nz`` (float32), or None.
- every other scalar vertex property goes into ``attributes[name]`` with the file's dtype
  (e.g. the L-System's int ``label`` and ``instance``). Other elements (``face``...) and
  list properties are skipped.

Files are read as plyfile, Open3D and trimesh read them: when the vertex element is whole
but something after it is not (extra rows at the end, as MeshLab writes; a truncated or
malformed face element), the vertices are returned and a :class:`PlyWarning` says what was
ignored. ``strict=True`` makes that a :class:`PlyError`. Problems in or before the vertex
element, and headers claiming more data than the file holds, are always a ``PlyError``.

Writes are atomic (the native writer goes through a temporary file in the same folder,
fsync and rename): a failed write leaves the previous file at the path as it was. Property
names and comments must be ASCII, as other readers require.

3DGS models (:func:`read_splat_ply`, :func:`write_splat_ply`) use the INRIA layout
(binary little endian float32: x y z nx ny nz f_dc_0..2 f_rest_* opacity scale_0..2
rot_0..3, f_rest channel-major). It is a naming convention over float32 columns, so it is
done here on top of the generic reader and writer: no conversion touches the values, and a
round trip is bit-exact. Normals are optional on read and written as zeros. A labelled
model has two more properties after the INRIA ones, ``int label`` (class) and
``int instance`` (object id, -1 where none); viewers that ignore extra properties still
open the file. On read, either one alone is accepted (the other becomes -1), as integers
or as integer-valued floats.
"""

from __future__ import annotations

import os
import re
import warnings
from collections.abc import Iterable

import numpy as np

from plantdreamer import _core
from plantdreamer.atomic import atomic_path
from plantdreamer.cloud import PointCloud
from plantdreamer.errors import InputError, PlyError, PlyWarning
from plantdreamer.gaussians import Gaussians, sh_coeff_count
from plantdreamer.labels import NO_INSTANCE, as_int_labels

__all__ = [
    "check_ply_file",
    "read_ply",
    "read_ply_columns",
    "read_splat_ply",
    "write_ply",
    "write_splat_ply",
]

PathLike = str | os.PathLike[str]

_COLOR_NAMES = (
    ("red", "green", "blue"),
    ("diffuse_red", "diffuse_green", "diffuse_blue"),
    ("r", "g", "b"),
)
_COLOR_SCALE = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}
_PLY_DTYPES = tuple(
    np.dtype(t)
    for t in (np.int8, np.uint8, np.int16, np.uint16, np.int32, np.uint32, np.float32, np.float64)
)


def _read_fields(
    path: PathLike, groups: list[list[str]], strict: bool
) -> list[tuple[list[str], np.ndarray]]:
    _, fields, _, _, problems = _core.read_ply_vertex(os.fspath(path), groups, strict)
    for problem in problems:
        # stacklevel 3: the caller of the public reader.
        warnings.warn(problem, PlyWarning, stacklevel=3)
    return fields


def check_ply_file(path: PathLike, what: str = "PLY") -> None:
    """A look before a command deletes or loads anything: ``path`` is a readable PLY file
    whose vertex element will load (its header's claims against the file's length, or the
    rows read where their size is not fixed: ``_core.check_ply_vertex``)."""
    try:
        with open(path, "rb") as f:
            head = f.read(1 << 16)
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} not found: {path}") from None
    except IsADirectoryError:
        raise InputError(f"{what} {path} is a folder, not a PLY file") from None
    except OSError as exc:
        raise InputError(f"{what} {path} cannot be read: {exc.strerror or exc}") from None
    if not (head.startswith((b"ply\n", b"ply\r\n")) and b"end_header" in head):
        raise PlyError(f"{what} {path} is not a PLY file (no PLY header)")
    try:
        _core.check_ply_vertex(os.fspath(path))
    except PlyError as exc:
        raise PlyError(f"{what} {exc}") from None


def read_ply_columns(path: PathLike, *, strict: bool = False) -> dict[str, np.ndarray]:
    """The scalar properties of the vertex element, by name in header order, as stored."""
    return {names[0]: values for names, values in _read_fields(path, [], strict)}


# Read as [N, 3] blocks in one pass when a file stores them with one type.
_GROUPS = [["x", "y", "z"], ["nx", "ny", "nz"], *[list(names) for names in _COLOR_NAMES]]


def read_ply(path: PathLike, *, strict: bool = False) -> PointCloud:
    """Reads a point cloud (see the module docstring for what each field becomes).

    ``strict``: a problem after the vertex element is a PlyError, not a PlyWarning.
    """
    blocks: dict[tuple[str, ...], np.ndarray] = {}
    cols: dict[str, np.ndarray] = {}
    for names, values in _read_fields(path, _GROUPS, strict):
        if len(names) == 1:
            cols[names[0]] = values
        else:
            blocks[tuple(names)] = values
            cols.update({n: values[:, i] for i, n in enumerate(names)})

    def block(names: tuple[str, ...]) -> np.ndarray:
        # One [N, 3] array: the gathered block if there is one, else stacked columns.
        got = blocks.get(names)
        for n in names:
            del cols[n]
        return got if got is not None else np.stack([cols_all[n] for n in names], axis=1)

    cols_all = dict(cols)
    missing = [a for a in ("x", "y", "z") if a not in cols]
    if missing:
        raise PlyError(f"{os.fspath(path)}: the vertex element has no {'/'.join(missing)} property")
    xyz = [cols[a] for a in ("x", "y", "z")]
    dtype = np.float64 if any(c.dtype == np.float64 for c in xyz) else np.float32
    positions = block(("x", "y", "z")).astype(dtype, copy=False)

    colors = None
    for group in _COLOR_NAMES:
        if all(n in cols for n in group):
            kinds = {cols[n].dtype for n in group}
            if len(kinds) != 1:
                continue
            kind = kinds.pop()
            if kind in _COLOR_SCALE:
                colors = block(group).astype(np.float32) / np.float32(_COLOR_SCALE[kind])
            elif kind.kind == "f":
                colors = block(group).astype(np.float32, copy=False)
            else:
                continue
            break

    normals = None
    if all(n in cols for n in ("nx", "ny", "nz")):
        normals = block(("nx", "ny", "nz")).astype(np.float32, copy=False)
    attributes = {n: np.ascontiguousarray(v) for n, v in cols.items()}
    return PointCloud(positions=positions, colors=colors, normals=normals, attributes=attributes)


def _ply_column(name: str, values: np.ndarray) -> np.ndarray:
    """A 1-D contiguous array in one of the eight PLY types, or InputError."""
    v = np.asarray(values)
    if v.dtype == np.bool_:
        v = v.astype(np.uint8)
    elif v.dtype == np.float16:
        v = v.astype(np.float32)
    elif v.dtype in (np.dtype(np.int64), np.dtype(np.uint64)):
        # PLY has no 64-bit integers: narrow when the values fit, never wrap.
        narrow = np.int32 if v.dtype == np.int64 else np.uint32
        info = np.iinfo(narrow)
        if v.size and (v.min() < info.min or v.max() > info.max):
            raise InputError(f"attribute {name!r} has values outside the 32-bit range of PLY")
        v = v.astype(narrow)
    if v.dtype not in _PLY_DTYPES:
        raise InputError(f"attribute {name!r} has dtype {v.dtype}, which PLY cannot store")
    return np.ascontiguousarray(v)


def write_ply(
    path: PathLike,
    cloud: PointCloud,
    binary: bool = True,
    *,
    color_dtype: str = "uchar",
    comments: Iterable[str] = (),
) -> None:
    """Writes a point cloud as PLY (binary little endian by default, else ascii).

    Positions are written as float (or double when they are float64), normals as float,
    colours as uchar 0-255 (rounded from [0, 1], clipped) by default or as float 0-1 with
    ``color_dtype="float"``, and every attribute as its own property (int64 narrowed to
    int32 when the values fit, bool as uchar).
    """
    cloud.validate()
    pos = cloud.positions
    if pos.dtype != np.float64:
        pos = pos.astype(np.float32, copy=False)
    fields: list[tuple[list[str], np.ndarray]] = [(["x", "y", "z"], np.ascontiguousarray(pos))]
    if cloud.normals is not None:
        n = np.ascontiguousarray(cloud.normals, dtype=np.float32)
        fields.append((["nx", "ny", "nz"], n))
    if cloud.colors is not None:
        c = np.asarray(cloud.colors, dtype=np.float32)
        if color_dtype == "uchar":
            if not np.isfinite(c).all():
                raise InputError("colors contain NaN or Inf; they cannot be written as uchar")
            q = np.clip(c, 0.0, 1.0)  # one temporary, then in place
            q *= np.float32(255.0)
            np.rint(q, out=q)
            c = q.astype(np.uint8)
        elif color_dtype != "float":
            raise InputError(f"color_dtype must be 'uchar' or 'float', got {color_dtype!r}")
        fields.append((["red", "green", "blue"], np.ascontiguousarray(c)))
    taken = {name for names, _ in fields for name in names}
    for name, values in cloud.attributes.items():
        if name in taken:
            raise InputError(f"attribute {name!r} clashes with a standard vertex property")
        fields.append(([name], _ply_column(name, values)))
    with atomic_path(path) as tmp:
        _core.write_ply_vertex(os.fspath(tmp), fields, binary, list(comments))


_F_REST = re.compile(r"f_rest_(\d+)$")
_SPLAT_REQUIRED = (
    "x",
    "y",
    "z",
    "f_dc_0",
    "f_dc_1",
    "f_dc_2",
    "opacity",
    "scale_0",
    "scale_1",
    "scale_2",
    "rot_0",
    "rot_1",
    "rot_2",
    "rot_3",
)


def read_splat_ply(path: PathLike, *, strict: bool = False) -> Gaussians:
    """Reads a 3DGS model in the INRIA layout; the SH degree follows from the f_rest count.

    ``strict``: a problem after the vertex element is a PlyError, not a PlyWarning.
    """
    cols = {names[0]: values for names, values in _read_fields(path, [], strict)}
    where = os.fspath(path)
    missing = [n for n in _SPLAT_REQUIRED if n not in cols]
    if missing:
        raise PlyError(f"{where}: not a 3DGS PLY, missing vertex properties {missing}")
    rest_ids = sorted(int(m.group(1)) for n in cols if (m := _F_REST.match(n)))
    if rest_ids != list(range(len(rest_ids))):
        raise PlyError(f"{where}: f_rest properties are not numbered 0..{len(rest_ids) - 1}")
    degrees = {3 * (sh_coeff_count(d) - 1): d for d in range(4)}
    if len(rest_ids) not in degrees:
        raise PlyError(
            f"{where}: {len(rest_ids)} f_rest properties match no SH degree 0-3 "
            f"(expected one of {sorted(degrees)})"
        )
    k = sh_coeff_count(degrees[len(rest_ids)])

    def f32(*names: str) -> np.ndarray:
        return np.stack([cols[n] for n in names], axis=1).astype(np.float32, copy=False)

    n = len(cols["x"])
    sh = np.empty((n, k, 3), dtype=np.float32)
    sh[:, 0, :] = f32("f_dc_0", "f_dc_1", "f_dc_2")
    if k > 1:
        rest = f32(*(f"f_rest_{i}" for i in rest_ids))  # [N, 3 * (K - 1)], channel-major
        sh[:, 1:, :] = rest.reshape(n, 3, k - 1).transpose(0, 2, 1)
    return Gaussians(
        means=f32("x", "y", "z"),
        quats=f32("rot_0", "rot_1", "rot_2", "rot_3"),
        log_scales=f32("scale_0", "scale_1", "scale_2"),
        opacity_logits=cols["opacity"].astype(np.float32, copy=False),
        sh=sh,
        labels=_splat_labels(cols, n, where),
    )


def _splat_labels(cols: dict[str, np.ndarray], n: int, where: str) -> np.ndarray | None:
    if "label" not in cols and "instance" not in cols:
        return None
    labels = np.full((n, 2), NO_INSTANCE, dtype=np.int32)
    for i, name in enumerate(("label", "instance")):
        if name in cols:
            try:
                labels[:, i] = as_int_labels(name, cols[name])
            except InputError as exc:
                raise PlyError(f"{where}: {exc}") from None
    return labels


def write_splat_ply(
    path: PathLike,
    gaussians: Gaussians,
    sh_degree: int | None = None,
    labels: bool = True,
    *,
    comments: Iterable[str] = (),
) -> None:
    """Writes a 3DGS model in the INRIA layout (binary little endian, float32).

    ``sh_degree`` pads (with zeros) or truncates the SH first; ``sh_degree=3`` makes files
    that strict viewers (which expect 45 f_rest properties) accept. A labelled model gets
    ``label`` and ``instance`` (int32) after the INRIA properties unless ``labels=False``.
    """
    g = gaussians if sh_degree is None else gaussians.with_sh_degree(sh_degree)
    g.validate()
    n, k = len(g), g.sh.shape[1]

    def block(a: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(a, dtype=np.float32)

    rest = g.sh[:, 1:, :].transpose(0, 2, 1).reshape(n, 3 * (k - 1))  # channel-major
    fields = [
        (["x", "y", "z"], block(g.means)),
        (["nx", "ny", "nz"], np.zeros((n, 3), dtype=np.float32)),
        (["f_dc_0", "f_dc_1", "f_dc_2"], block(g.sh[:, 0, :])),
    ]
    if k > 1:
        fields.append(([f"f_rest_{i}" for i in range(3 * (k - 1))], block(rest)))
    fields += [
        (["opacity"], block(g.opacity_logits)),
        (["scale_0", "scale_1", "scale_2"], block(g.log_scales)),
        (["rot_0", "rot_1", "rot_2", "rot_3"], block(g.quats)),
    ]
    if labels and g.labels is not None:
        fields.append((["label", "instance"], np.ascontiguousarray(g.labels, dtype=np.int32)))
    with atomic_path(path) as tmp:
        _core.write_ply_vertex(os.fspath(tmp), fields, True, list(comments))
