"""Claiming where a command writes: one run at a time, and never a mix of two runs.

A command that writes a set of outputs first *claims* them:

- it takes an exclusive lock (``fcntl.flock`` on a lock file beside the outputs), so a
  second run on the same outputs fails at once with a clear message instead of
  interleaving its files with the first one's;
- it refuses outputs that already exist, unless ``overwrite`` is given; then it deletes the
  previous run's outputs (the files this command writes, and nothing else) before writing,
  so a run that is interrupted never leaves new files beside old ones.

Creating the lock file is also the writability check (a fixed probe name that is created
and deleted would race between two runs). The lock file is removed when the claim ends.
"""

from __future__ import annotations

import fcntl
import os
import shutil
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from plantdreamer.errors import InputError

__all__ = ["LOCK_NAME", "claim_files", "claim_folder", "locked"]

LOCK_NAME = ".plantdreamer.lock"


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
    owned: Iterable[str] = (),
    allow_existing: bool = False,
) -> Iterator[Path]:
    """Locks ``folder`` and checks it is empty (``allow_existing``: continuing a run there).

    With ``overwrite``, the entries matching the ``owned`` glob patterns are deleted first,
    in the given order (put the file that marks a finished run, such as run.json, first).
    """
    path = Path(folder)
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
    files = [Path(p) for p in paths]
    first = files[0]
    with locked(first.with_name(f".{first.name}.lock"), str(first)):
        existing = [p for p in files if p.exists() or p.is_symlink()]
        if existing and not overwrite:
            raise InputError(
                f"{existing[0]} exists; pass --overwrite to replace it, or choose another output"
            )
        for p in existing:
            _delete(p)
        yield files


def _remove(folder: Path, patterns: Iterable[str]) -> None:
    for pattern in patterns:
        for p in sorted(folder.glob(pattern)):
            _delete(p)


def _delete(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)
