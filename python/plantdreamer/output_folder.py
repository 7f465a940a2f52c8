"""Claiming where a command writes: one run at a time, and never a mix of two runs.

A command that writes a set of outputs first *claims* them:

- it takes an exclusive lock (``fcntl.flock`` on a lock file beside the outputs), so a
  second run on the same outputs fails at once with a clear message instead of
  interleaving its files with the first one's;
- it refuses outputs that already exist, unless ``overwrite`` is given; then it deletes the
  previous run's outputs (the files this command writes, and nothing else) before writing,
  so a run that is interrupted never leaves new files beside old ones. What a command
  owns is named exactly: literal entry names (a plant named ``*-s0000`` owns that folder,
  not every name ending in ``-s0000``) or a regular expression an entry's whole name must
  match (``view_NNN.png``, never ``*.png``, which would take a user's pictures); an
  output file that is a folder is refused, never emptied.

Creating the lock file is also the writability check (a fixed probe name that is created
and deleted would race between two runs). The lock file is removed when the claim ends.
"""

from __future__ import annotations

import fcntl
import os
import re
import shutil
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path, PurePath

from plantdreamer.errors import InputError

__all__ = ["LOCK_NAME", "Owned", "claim_files", "claim_folder", "locked", "output_file"]

LOCK_NAME = ".plantdreamer.lock"
# An entry a command writes in its folder: a literal name (a relative path inside the
# folder) or a pattern the whole name of an entry of the folder matches.
Owned = str | re.Pattern[str]


@contextmanager
def locked(lock_path: Path, what: str, holder: str = "plantdreamer run") -> Iterator[None]:
    """Holds an exclusive lock on ``lock_path`` (created if missing) for the block; a second
    claim fails with "``what`` is in use by another ``holder``"."""
    folder = lock_path.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise PermissionError(f"output folder {folder} is not writable: {exc}") from exc
    while True:
        try:
            fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as exc:
            raise PermissionError(f"output folder {folder} is not writable: {exc}") from exc
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise InputError(
                f"{what} is in use by another {holder} (lock {lock_path}); "
                "wait for it to finish or write elsewhere"
            ) from None
        # The holder before us may have removed the file after we opened it: retry on the
        # file now at the path, so two runs never hold locks on two different files.
        try:
            same = os.stat(lock_path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        yield
    finally:
        Path(lock_path).unlink(missing_ok=True)
        os.close(fd)


@contextmanager
def claim_folder(
    folder: str | os.PathLike[str],
    *,
    overwrite: bool = False,
    owned: Iterable[Owned] = (),
    allow_existing: bool = False,
) -> Iterator[Path]:
    """Locks ``folder`` and checks it is empty (``allow_existing``: continuing a run there).

    With ``overwrite``, the ``owned`` entries (literal names, or compiled patterns matched
    against whole entry names) are deleted first, in the given order (put the file that
    marks a finished run, such as run.json, first). A literal name that is not a plain
    relative path inside ``folder`` is refused before anything is deleted.
    """
    path = Path(folder)
    owned = list(owned)
    for entry in owned:
        if isinstance(entry, str):
            _check_name(entry)
    if path.exists() and not path.is_dir():
        raise PermissionError(f"output folder {path} is not writable: it is a file")
    with locked(path / LOCK_NAME, f"output folder {path}"):
        if overwrite:
            _remove(path, owned)
        elif not allow_existing:
            entries = sorted(p.name for p in path.iterdir() if p.name != LOCK_NAME)
            if entries:
                shown = ", ".join(entries[:3]) + (", ..." if len(entries) > 3 else "")
                raise InputError(
                    f"output folder {path} is not empty ({shown}); pass --overwrite to "
                    "replace its outputs, or choose another folder"
                )
        yield path


@contextmanager
def claim_files(
    paths: Iterable[str | os.PathLike[str]], *, overwrite: bool = False
) -> Iterator[list[Path]]:
    """Locks the outputs ``paths`` (one folder) and refuses existing ones unless ``overwrite``;
    with ``overwrite`` they are all deleted first, so no stale companion file survives."""
    files = [output_file(p) for p in paths]
    first = files[0]
    with locked(first.with_name(f".{first.name}.lock"), str(first)):
        existing = [p for p in files if p.exists() or p.is_symlink()]
        folders = [p for p in existing if p.is_dir() and not p.is_symlink()]
        if folders:
            raise InputError(
                f"{folders[0]} is a folder, not a file this command writes; "
                "name a file, or choose another output"
            )
        if existing and not overwrite:
            raise InputError(
                f"{existing[0]} exists; pass --overwrite to replace it, or choose another output"
            )
        for p in existing:
            _delete(p)
        yield files


def output_file(path: str | os.PathLike[str], what: str = "output") -> Path:
    """``path`` as a file to write: refused when it names a folder (``.``, ``dir/``, an
    existing folder), so no companion name is made from it and nothing in it is touched."""
    out = Path(path)
    if out.name in ("", ".", "..") or str(path).endswith(os.sep) or out.is_dir():
        raise InputError(f"{what} {path} is a folder; name the file to write")
    return out


def _check_name(name: str) -> None:
    parts = PurePath(name).parts
    if not parts or PurePath(name).is_absolute() or ".." in parts:
        raise InputError(f"{name!r} is not a name inside the output folder")


def _remove(folder: Path, owned: Iterable[Owned]) -> None:
    for entry in owned:
        if isinstance(entry, str):
            _delete(folder / entry)
        elif folder.is_dir():
            for p in sorted(folder.iterdir()):
                if entry.fullmatch(p.name):
                    _delete(p)


def _delete(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)
