"""What a command owns in its folder (``Owned``: exact names, its folders, patterns), and
the survey of the folder as it is before anything is deleted: the command's files (and
its killed writes' temporaries), its folders, and anything in its way (``output_folder``
refuses with the list, deleting nothing)."""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path, PurePath

from plantdreamer.errors import InputError
from plantdreamer.output_locks import LOCK_NAME
from plantdreamer.temporaries import STAGING, is_temporary_of, name_max, temporary_target

__all__ = ["Owned", "OwnedSpec", "Survey", "check_owned_name", "survey"]

# An entry a command writes in its folder, as a relative POSIX path: a literal file name,
# a literal folder name ending in "/" (its contents: the entries under it), or a pattern a
# file's whole relative path matches.
Owned = str | re.Pattern[str]


@dataclass
class Survey:
    """What a command owns in a folder as it is now: its files (in ``owned`` order: the
    file that marks a finished run first), its folders (deepest first) and anything in its
    way (foreign files in its folders, links or folders where it writes)."""

    files: list[Path] = field(default_factory=list)
    folders: list[Path] = field(default_factory=list)
    foreign: list[str] = field(default_factory=list)

    def refuse(self, root: Path) -> None:
        if self.foreign:
            shown = ", ".join(self.foreign[:5]) + (
                f" and {len(self.foreign) - 5} more" if len(self.foreign) > 5 else ""
            )
            raise InputError(
                f"{root} holds, where this command writes, what it does not write: {shown}; "
                "nothing was deleted: move them away, or choose another output folder"
            )


class OwnedSpec:
    """A command's ``Owned`` entries, checked, with its folders apart."""

    def __init__(self, owned: Iterable[Owned]) -> None:
        self.entries = list(owned)
        for entry in self.entries:
            if isinstance(entry, str):
                check_owned_name(entry)
        self.folders = {
            e.rstrip("/") for e in self.entries if isinstance(e, str) and e.endswith("/")
        }

    def file_rank(self, rel: str) -> int | None:
        for i, entry in enumerate(self.entries):
            if entry == rel if isinstance(entry, str) else entry.fullmatch(rel):
                return i
        return None

    def holds(self, rel: str) -> bool:
        """Whether the relative path is one of the outputs or lies in an output folder."""
        if self.file_rank(rel) is not None:
            return True
        return any(rel == d or rel.startswith(d + "/") for d in self.folders)

    def owns_temporary(self, rel_dir: str, entry: str, limit: int) -> bool:
        """Whether ``entry`` in ``rel_dir`` is a killed write's temporary of one of the
        command's files (or, at the top, a staging folder of its exports)."""
        carried = temporary_target(entry)
        if carried is None:
            return False
        if not rel_dir and carried == STAGING:
            return True
        prefix = f"{rel_dir}/" if rel_dir else ""
        if self.file_rank(prefix + carried) is not None:
            return True
        literals = [e for e in self.entries if isinstance(e, str) and not e.endswith("/")]
        return any(
            is_temporary_of(entry, e[len(prefix) :], limit)
            for e in literals
            if e.startswith(prefix) and "/" not in e[len(prefix) :]
        )


def survey(folder: Path, owned: Iterable[Owned]) -> Survey:
    """What the command owns in ``folder`` now (see ``Survey``); reads only, follows no link.
    The temporaries of killed atomic writes, at the top and in its folders, are its own."""
    spec = OwnedSpec(owned)
    found = Survey()
    ranked: list[tuple[int, Path]] = []
    limit = name_max(folder)

    def walk(rel_dir: str) -> None:
        inside = bool(rel_dir)
        with os.scandir(folder / rel_dir if inside else folder) as entries:
            listing = sorted(entries, key=lambda e: e.name)
        for entry in listing:
            rel = f"{rel_dir}/{entry.name}" if inside else entry.name
            is_link = entry.is_symlink()
            is_dir = entry.is_dir(follow_symlinks=False)
            if not inside and entry.name == LOCK_NAME:
                continue
            if not is_link and spec.owns_temporary(rel_dir, entry.name, limit):
                ranked.append((-1, folder / rel))  # a killed write's temporary: first
            elif rel in spec.folders:
                if is_dir:
                    walk(rel)
                    found.folders.append(folder / rel)
                else:
                    found.foreign.append(f"{rel} ({'a link' if is_link else 'a file'})")
            elif (rank := spec.file_rank(rel)) is not None:
                if is_dir:
                    found.foreign.append(f"{rel}/ (a folder)")
                else:
                    ranked.append((rank, folder / rel))
            elif inside:
                found.foreign.append(rel + ("/" if is_dir else ""))

    if folder.is_dir():  # the folder itself as given (a link the user chose); none inside
        walk("")
    found.files = [path for _, path in sorted(ranked, key=lambda r: r[0])]
    return found


def check_owned_name(name: str) -> None:
    parts = PurePath(name).parts
    if not parts or PurePath(name).is_absolute() or ".." in parts:
        raise InputError(f"{name!r} is not a name inside the output folder")
