"""Atomic file writes: a file is either its old self or complete, never truncated.

Every file plantdreamer writes goes through :func:`atomic_path`: the writer fills a temporary
file in the same folder (same file system, so the rename is atomic), the data is flushed to
disk (fsync), the temporary file is renamed over the target (``os.replace``) and the folder
entry is flushed too. If anything fails (a full disk, a file-size limit, Ctrl-C) the
temporary file is removed and the previous file is left as it was.

The temporary name keeps the target's suffix (``.plant.ply.<16 hex>.tmp.ply``), so writers
that pick a format from the suffix (imageio, Pillow, matplotlib, trimesh) work unchanged,
and carries a check the program verifies (``temporaries``): a process killed inside a
write (SIGKILL, a power cut) cannot remove its temporary, and the next run that claims the
folder removes it (``output_folder``), never a user's file of a similar name. A target
whose name is as long as the file system allows still gets a temporary (its name is
shortened). Several outputs replaced together are built in a ``staging_folder`` and moved
in together (``exports.dataset_files``).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from plantdreamer.temporaries import STAGING, name_max, temporary_name

__all__ = [
    "atomic_path",
    "atomic_write",
    "fsync_folder",
    "staging_folder",
    "write_bytes",
    "write_image",
    "write_json",
    "write_text",
]

PathLike = str | os.PathLike[str]


@contextmanager
def atomic_path(path: PathLike) -> Iterator[Path]:
    """Yields a temporary path beside ``path``; on a clean exit it replaces ``path``.

    The folder must exist (a missing folder is a FileNotFoundError, as with ``open``).
    """
    target = Path(path)
    tmp = _new_temporary(target)
    try:
        yield tmp
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # created 0600 (private until complete); shared
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_folder(target.parent)


def _new_temporary(target: Path) -> Path:
    """An empty file of a new temporary name beside ``target``, made exclusively."""
    limit = name_max(target.parent)
    while True:
        tmp = target.with_name(temporary_name(target.name, limit=limit))
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
            return tmp
        except FileExistsError:  # the same random token: draw another
            continue


def staging_folder(folder: PathLike) -> Path:
    """A new, empty folder inside ``folder`` (same file system: its entries move in by
    rename), named as a temporary."""
    while True:
        stage = Path(folder) / temporary_name(STAGING)
        try:
            stage.mkdir(mode=0o700)
            return stage
        except FileExistsError:
            continue


def atomic_write(path: PathLike, write: Callable[[Path], object]) -> None:
    """Calls ``write(tmp_path)`` on a temporary file beside ``path`` (creating its folder),
    then renames it over ``path``."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        write(tmp)


def write_bytes(path: PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(data)


def write_text(path: PathLike, text: str) -> None:
    write_bytes(path, text.encode("utf-8"))


def write_json(path: PathLike, data: Any, **dumps: Any) -> None:
    """``json.dumps(data, indent=2, **dumps)`` plus a final newline."""
    write_text(path, json.dumps(data, **{"indent": 2, **dumps}) + "\n")


def write_image(path: PathLike, image: Any, **options: Any) -> None:
    """An array (imageio) or a PIL image; the format follows ``path``'s suffix."""
    if hasattr(image, "save") and not hasattr(image, "shape"):  # PIL.Image.Image
        with atomic_path(path) as tmp:
            image.save(tmp, **options)
        return
    import imageio.v3 as iio

    with atomic_path(path) as tmp:
        iio.imwrite(tmp, image, extension=Path(path).suffix or ".png", **options)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def fsync_folder(folder: Path) -> None:
    """Flushes the rename itself; some file systems cannot open a folder, which is fine."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
