"""Names a command writes: a value that becomes part of a path (a species, a plant name),
and a single output file, checked before anything is deleted (``output_folder``)."""

from __future__ import annotations

import os
import re
from pathlib import Path

from plantdreamer.errors import InputError
from plantdreamer.temporaries import name_max

__all__ = [
    "PATH_PART",
    "check_name",
    "check_writable_name",
    "file_lock_name",
    "new_file",
    "output_file",
]

PathLike = str | os.PathLike[str]
# A value that becomes one part of a path (a species, a plant name): never a path itself.
PATH_PART = re.compile(r"[A-Za-z0-9_][A-Za-z0-9._ -]{0,99}")
PATH_MAX = 4096  # bytes in a path (Linux)


def check_name(value: str, what: str) -> str:
    """``value`` (a species, a plant name) as one plain part of a path; InputError else."""
    if not isinstance(value, str) or not PATH_PART.fullmatch(value) or value.strip() != value:
        raise InputError(
            f"{what} {value!r} becomes part of a path: use letters, digits, '-', '_', '.' "
            "or spaces (not first), never a path"
        )
    return value


def output_file(path: PathLike, what: str = "output") -> Path:
    """``path`` as a file to write: refused when it names a folder (``.``, ``dir/``, an
    existing folder), so no companion name is made from it and nothing in it is touched,
    and when the file system cannot take its name (longer than it allows, a NUL), so the
    check comes before anything is deleted."""
    out = Path(path)
    if out.name in ("", ".", "..") or str(path).endswith(os.sep):
        raise InputError(f"{what} {path} is a folder; name the file to write")
    check_writable_name(out, what)
    if out.is_dir():
        raise InputError(f"{what} {path} is a folder; name the file to write")
    return out


def check_writable_name(path: Path, what: str) -> None:
    """Refuses a path the file system cannot take as a file name: a NUL, a name longer
    than its limit (bytes), a path longer than ``PATH_MAX``."""
    text = str(path)
    if "\0" in text:
        raise InputError(f"{what} {text!r} holds a NUL character, which no file name can")
    limit = name_max(path.parent)
    size = len(os.fsencode(path.name))
    if size > limit:
        raise InputError(
            f"{what} {path.name[:40]}... is {size} bytes long; this file system takes names "
            f"of at most {limit} bytes: choose a shorter name"
        )
    if len(os.fsencode(os.path.abspath(path))) >= PATH_MAX:
        raise InputError(f"{what} {text[:40]}... is longer than a path may be ({PATH_MAX} bytes)")


def file_lock_name(path: Path) -> str:
    """The lock file beside a single output (``.NAME.lock``; a long name shortened)."""
    room = name_max(path.parent) - len(".") - len(".lock")
    name = path.name
    while len(os.fsencode(name)) > room and len(name) > 1:
        name = name[:-1]
    return f".{name}.lock"


def new_file(path: PathLike, what: str, *, overwrite: bool = False) -> Path:
    """A single output file the command replaces atomically (the previous one stays whole
    until the new one is complete): refused when it names a folder, and when it exists
    unless ``overwrite``."""
    out = output_file(path, what)
    if (out.exists() or out.is_symlink()) and not overwrite:
        raise InputError(f"{out} exists; pass --overwrite to replace it, or choose another {what}")
    return out
