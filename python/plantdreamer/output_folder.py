"""Claiming where a command writes: one run at a time, its own files only, never a mix of
two runs.

Every command that writes follows one ownership rule:

- it checks first that it can run (inputs readable, models found, settings valid: the
  caller's checks, made before the claim) and that none of its inputs lies among the
  outputs it would replace (``inputs``);
- it takes an exclusive lock (``fcntl.flock`` on a lock file beside the outputs), so a
  second run on the same outputs fails at once instead of interleaving its files;
- it refuses outputs that already exist, unless ``overwrite`` is given; then it deletes the
  files and folders it writes itself and nothing else. What a command owns is declared
  exactly (``Owned``): literal relative paths (a plant named ``*-s0000`` owns that folder,
  not every name ending in ``-s0000``), folders it makes (``tree``: ``renders/`` and the
  ``view_NNN.png`` in it) and regular expressions a relative path must match whole
  (``view_NNN.png``, never ``*.png``, which would take a user's pictures). Before anything
  is deleted the folder is surveyed: a folder of the command's own name that holds a file
  it does not write, a link where it writes a folder, or a folder where it writes a file
  is refused with the list, and nothing is deleted. Links are never followed: a link the
  command owns is removed itself, its target left alone;
- the temporaries that a killed run left of the files it writes (``temporaries``: names
  the program verifies, never a user's ``.backup.tmp``) are removed when the next run
  claims the folder; a refused claim deletes nothing, temporaries included;
- the name of every file it writes is checked before anything is deleted (``output_file``:
  no longer than the file system takes, no NUL), so a replacement cannot fail on its name
  after the old output is gone.

The locks are ``output_locks``: one run per folder, none inside a folder another run holds.
Creating the lock file is also the writability check (a fixed probe name that is created
and deleted would race between two runs). The lock file is removed when the claim ends.
"""

from __future__ import annotations

import os
import re
import shutil
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from plantdreamer.errors import InputError
from plantdreamer.output_locks import LOCK_NAME, locked
from plantdreamer.output_names import check_name, file_lock_name, new_file, output_file
from plantdreamer.output_survey import Owned, OwnedSpec, check_owned_name, survey
from plantdreamer.temporaries import is_temporary_of, name_max

__all__ = [
    "LOCK_NAME",
    "Owned",
    "check_inputs_outside",
    "check_name",
    "claim_files",
    "claim_folder",
    "locked",
    "new_file",
    "output_file",
    "remove_owned",
    "remove_temporaries",
    "survey",
    "tree",
]

PathLike = str | os.PathLike[str]


def tree(name: str, *contents: Owned) -> tuple[Owned, ...]:
    """A folder ``name`` the command makes, and what it writes in it (relative to it)."""
    check_owned_name(name)
    out: list[Owned] = [name.rstrip("/") + "/"]
    for entry in contents:
        if isinstance(entry, str):
            out.append(f"{name.rstrip('/')}/{entry}")
        else:
            out.append(re.compile(f"{re.escape(name.rstrip('/'))}/(?:{entry.pattern})"))
    return tuple(out)


def remove_owned(folder: Path, owned: Iterable[Owned]) -> None:
    """Deletes what the command owns in ``folder``, after refusing (deleting nothing) when
    anything in its way is not its own."""
    found = survey(folder, owned)
    found.refuse(folder)
    for path in found.files:
        if path.is_dir() and not path.is_symlink():  # a killed export's staging folder
            shutil.rmtree(path)
        else:
            path.unlink(missing_ok=True)
    for path in found.folders:
        try:
            path.rmdir()
        except OSError:  # something appeared since the survey: left, never emptied
            pass


def check_inputs_outside(folder: Path, owned: Iterable[Owned], inputs: Iterable[PathLike]) -> None:
    """Refuses inputs that lie among the outputs the command writes in ``folder``."""
    spec = OwnedSpec(owned)
    root = folder.resolve()
    for given in inputs:
        path = Path(given).resolve()
        if path == root:
            continue
        if path.is_relative_to(root) and spec.holds(path.relative_to(root).as_posix()):
            raise InputError(
                f"{given} is an input of this command and lies among the outputs it writes in "
                f"{folder}; write the outputs to another folder"
            )


@contextmanager
def claim_folder(
    folder: PathLike,
    *,
    overwrite: bool = False,
    owned: Iterable[Owned] = (),
    allow_existing: bool = False,
    inputs: Iterable[PathLike] = (),
) -> Iterator[Path]:
    """Locks ``folder`` and checks it is empty (``allow_existing``: continuing a run there).

    ``inputs`` lying among the ``owned`` outputs are refused first. With ``overwrite``, the
    owned outputs are deleted (``remove_owned``: refused, nothing deleted, when anything in
    the way is not the command's). A killed run's temporaries are removed in every case.
    """
    path = Path(folder)
    owned = list(owned)
    spec = OwnedSpec(owned)  # checks the literal names before anything else
    check_inputs_outside(path, owned, inputs)
    if path.exists() and not path.is_dir():
        raise PermissionError(f"output folder {path} is not writable: it is a file")
    with _removed_if_refused(path), locked(path / LOCK_NAME, f"output folder {path}"):
        if overwrite:
            remove_owned(path, spec.entries)
        else:
            if not allow_existing:  # refused before any temporary goes
                limit = name_max(path)
                entries = sorted(
                    p.name
                    for p in path.iterdir()
                    if p.name != LOCK_NAME
                    and (p.is_symlink() or not spec.owns_temporary("", p.name, limit))
                )
                if entries:
                    shown = ", ".join(entries[:3]) + (", ..." if len(entries) > 3 else "")
                    raise InputError(
                        f"output folder {path} is not empty ({shown}); pass --overwrite "
                        "to replace its outputs, or choose another folder"
                    )
            remove_temporaries(path, spec.entries)
        yield path


@contextmanager
def claim_files(
    paths: Iterable[PathLike], *, overwrite: bool = False, inputs: Iterable[PathLike] = ()
) -> Iterator[list[Path]]:
    """Locks the outputs ``paths`` (one folder) and refuses existing ones unless ``overwrite``;
    with ``overwrite`` they are all deleted first, so no stale companion file survives. An
    input that is one of them is refused before anything is deleted."""
    files = [output_file(p) for p in paths]
    resolved = {p.resolve() for p in files}
    for given in inputs:
        if Path(given).resolve() in resolved:
            raise InputError(
                f"{given} is an input of this command and would be replaced by its output; "
                "name another output file"
            )
    first = files[0]
    lock = first.with_name(file_lock_name(first))
    with _removed_if_refused(first.parent), locked(lock, str(first)):
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
            p.unlink(missing_ok=True)  # a link goes itself; its target stays
        for p in files:  # a killed write's temporaries of these files
            if p.parent.is_dir():
                limit = name_max(p.parent)
                for stale in p.parent.iterdir():
                    if is_temporary_of(stale.name, p.name, limit) and stale.is_file():
                        stale.unlink(missing_ok=True)
        yield files


def remove_temporaries(folder: Path, owned: Iterable[Owned]) -> None:
    """The temporaries a killed write left of the command's files, at the top of ``folder``
    or in its command's folders (``Survey``: verified names of its own files only)."""
    if not folder.is_dir():
        return
    spec = OwnedSpec(owned)
    limit = name_max(folder)
    for rel_dir in ["", *sorted(spec.folders)]:
        place = folder / rel_dir if rel_dir else folder
        if place.is_symlink() or not place.is_dir():
            continue
        for entry in place.iterdir():
            if entry.is_symlink() or not spec.owns_temporary(rel_dir, entry.name, limit):
                continue
            if entry.is_dir():
                shutil.rmtree(entry)
            else:
                entry.unlink(missing_ok=True)


@contextmanager
def _removed_if_refused(folder: Path) -> Iterator[None]:
    """The folders up to ``folder`` that the block makes are removed again when it fails
    (a refused command leaves no empty folder of its own), if still empty."""
    made = []
    place = Path(os.path.abspath(folder))
    while not place.exists() and place != place.parent:
        made.append(place)
        place = place.parent
    try:
        yield
    except BaseException:
        for empty in made:
            try:
                empty.rmdir()
            except OSError:  # not empty (or gone): left as it is
                break
        raise
