"""One ``dataset`` process per output folder: the shared output lock
(``plantdreamer.output_folder.locked``) on ``DIR/.plantdreamer.lock``.

``flock`` is dropped by the kernel when the process dies, however it dies, so a killed run
never leaves a stale lock. The lock file exists while the dataset runs, so a worker also
uses it to check that it sees the output folder (a cluster needs it on shared storage).
"""

from __future__ import annotations

from contextlib import AbstractContextManager
from pathlib import Path

from plantdreamer.output_folder import LOCK_NAME, locked

__all__ = ["LOCK_NAME", "dataset_lock"]


def dataset_lock(out_dir: Path) -> AbstractContextManager[None]:
    return locked(out_dir / LOCK_NAME, f"dataset folder {out_dir}", "`plantdreamer dataset`")
