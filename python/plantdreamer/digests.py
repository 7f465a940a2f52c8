"""SHA-256 of a file's contents, the one digest the records use (a dataset plant's source
point cloud, the model files a run read)."""

from __future__ import annotations

import hashlib
import os
import threading
from pathlib import Path

# (real path, size, mtime in ns, inode) -> digest: a file is hashed once per process while
# it is unchanged (a dataset worker's plants share their model files).
_CACHE: dict[tuple[str, int, int, int], str] = {}
_LOCK = threading.Lock()


def file_digest(path: Path) -> str:
    """SHA-256 of a file's contents (read in 1 MiB blocks), as hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(1 << 20):
            digest.update(block)
    return digest.hexdigest()


def cached_file_digest(path: Path) -> str:
    """``file_digest``, computed once per process for a file of the same path, size, time
    of last change and inode."""
    real = os.path.realpath(path)
    stat = os.stat(real)
    key = (real, stat.st_size, stat.st_mtime_ns, stat.st_ino)
    with _LOCK:
        known = _CACHE.get(key)
    if known is None:
        known = file_digest(Path(real))
        with _LOCK:
            _CACHE[key] = known
    return known
