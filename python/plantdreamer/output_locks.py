"""One run at a time in a folder, and none inside a folder another run holds.

A command that writes takes an exclusive ``fcntl.flock`` on a lock file beside its outputs
(``.plantdreamer.lock`` in its folder, ``.NAME.lock`` beside a single file), so a second run
on the same outputs fails at once. The kernel drops the lock when the process dies, however
it dies, so a killed run never leaves a stale lock; the file is removed when the claim ends.

Locks are also checked upward: a folder a run holds is in use down to its last file, so a
command writing anywhere inside it (``render --out PLANT/renders`` while ``generate`` holds
``PLANT``) is refused, after its own lock is taken (of two runs starting together, one sees
the other). The holder writes a random token into its lock file; a lock whose token this
process holds (a group's plants inside the group's folder) or was handed by the process
that started it (``HELD_ENV``: a dataset's workers inside the dataset's folder) is its own.
"""

from __future__ import annotations

import fcntl
import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from plantdreamer.errors import InputError

__all__ = ["HELD_ENV", "LOCK_NAME", "check_not_inside_held", "held_tokens", "locked"]

LOCK_NAME = ".plantdreamer.lock"
# The tokens of the locks a parent process holds for the processes it starts (a dataset's
# workers), separated by commas.
HELD_ENV = "PLANTDREAMER_HELD_LOCKS"
_HELD: dict[str, int] = {}  # the tokens of the locks this process holds (how many times)


@contextmanager
def locked(lock_path: Path, what: str, holder: str = "plantdreamer run") -> Iterator[None]:
    """Holds an exclusive lock on ``lock_path`` (created if missing) for the block; a second
    claim fails with "``what`` is in use by another ``holder``", and so does a claim inside
    a folder another run holds (``check_not_inside_held``)."""
    lock_path = Path(lock_path)
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
    token = secrets.token_hex(8)
    _HELD[token] = _HELD.get(token, 0) + 1
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, token.encode(), 0)
        check_not_inside_held(folder, what)
        yield
    finally:
        _HELD.pop(token, None)
        Path(lock_path).unlink(missing_ok=True)
        os.close(fd)


def held_tokens() -> list[str]:
    """The tokens of the locks this process holds or was handed (``HELD_ENV``): what a
    process it starts passes on in ``HELD_ENV``."""
    inherited = [t for t in os.environ.get(HELD_ENV, "").split(",") if t]
    return sorted({*_HELD, *inherited})


def check_not_inside_held(folder: Path, what: str) -> None:
    """Refuses ``folder`` when it, or a folder above it, is held by another run (a lock
    file there whose lock is taken, with a token that is not this process's). Called by
    ``locked`` once its lock is taken, and by a command before it says anything about what
    the folder holds (``generate``: an earlier run's checkpoint)."""
    place = Path(folder).resolve()
    for above in (place, *place.parents):
        holder = holder_token(above / LOCK_NAME)
        if holder is not None and holder not in held_tokens():
            raise InputError(
                f"{above} is in use by another plantdreamer run (lock {above / LOCK_NAME}) and "
                f"{what} lies inside it; wait for that run to finish or write elsewhere"
            )


def holder_token(lock_path: Path) -> str | None:
    """The token of the run holding ``lock_path`` ("" while it is being written), or None
    when no run holds it (no file, or a lock nobody takes)."""
    try:
        fd = os.open(lock_path, os.O_RDONLY | os.O_NOFOLLOW)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return os.pread(fd, 64, 0).decode("ascii", "replace").strip()
        except OSError:
            return None
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)
