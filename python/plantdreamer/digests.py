"""SHA-256 of a file's contents, the one digest the records use (a dataset plant's source
point cloud, a dataset card's models and LoRAs)."""

from __future__ import annotations

import hashlib
from pathlib import Path


def file_digest(path: Path) -> str:
    """SHA-256 of a file's contents (read in 1 MiB blocks), as hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(1 << 20):
            digest.update(block)
    return digest.hexdigest()
