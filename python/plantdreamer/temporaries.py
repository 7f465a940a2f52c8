"""The names of the temporaries plantdreamer makes, and how it knows them again.

A write in progress leaves a temporary beside its target (``atomic.atomic_path``), a set of
outputs replaced together is built in a staging folder (``atomic.staging_folder``) and a
hard link is made under a temporary name before it is renamed into place
(``exports.yolo.link_image``). A process killed meanwhile (SIGKILL, a power cut) cannot
remove them, so the next run that claims the folder does (``output_folder``).

A name alone would not say who made an entry: a user's ``.backup.20240101.tmp/`` or
``.notes.link`` looks like one. So every temporary carries a check the program verifies:

    .<name>.<token><tag>.tmp<suffix>     (a file; <suffix>: the target's, for writers that
    .staging.<token><tag>.tmp             pick a format from it)
    .<name>.<token><tag>.link

``<token>`` is 8 random hex digits and ``<tag>`` the first 8 hex digits of the SHA-256 of
the kind, name, token and suffix: a name without the right tag (1 chance in 4 billion for
a name made by anything else) is never taken for a temporary, so it is never removed.
``<name>`` is the target's name, shortened when the whole would pass the file system's
limit on a name (``NAME_MAX``), so a target of any valid length has a temporary.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import re
import secrets
from pathlib import Path

__all__ = [
    "NAME_MAX",
    "STAGING",
    "is_temporary",
    "is_temporary_of",
    "name_max",
    "temporary_name",
    "temporary_target",
]

NAME_MAX = 255  # bytes in one name, where the file system does not say otherwise
STAGING = "staging"  # the name part of a staging folder
KINDS = ("tmp", "link")
_FORM = re.compile(
    r"\.(?P<name>.+)\.(?P<token>[0-9a-f]{8})(?P<tag>[0-9a-f]{8})"
    r"\.(?P<kind>tmp|link)(?P<suffix>\.[^./]*)?",
    re.DOTALL,
)


def temporary_name(name: str, kind: str = "tmp", limit: int = NAME_MAX) -> str:
    """A new temporary's name for the target ``name`` (see the module docstring), at most
    ``limit`` bytes long."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    suffix = Path(name).suffix if kind == "tmp" and name != STAGING else ""
    token = secrets.token_hex(4)
    room = limit - len(os.fsencode(f"..{token}{token}.{kind}{suffix}"))
    short = _shortened(name, room)
    return f".{short}.{token}{_tag(kind, short, token, suffix)}.{kind}{suffix}"


def is_temporary(entry: str) -> bool:
    """Whether ``entry`` (a name in a folder) is a temporary plantdreamer made."""
    found = _FORM.fullmatch(entry)
    if found is None:
        return False
    kind, suffix = found["kind"], found["suffix"] or ""
    if kind == "link" and suffix:
        return False
    expected = _tag(kind, found["name"], found["token"], suffix)
    return hmac.compare_digest(found["tag"], expected)


def name_max(folder: Path) -> int:
    """The longest name (bytes) the file system of ``folder`` (or its nearest existing
    parent) takes."""
    place = Path(folder)
    while not place.is_dir() and place != place.parent:
        place = place.parent
    try:
        return int(os.pathconf(place, "PC_NAME_MAX"))
    except (OSError, ValueError):
        return NAME_MAX


def _tag(kind: str, name: str, token: str, suffix: str) -> str:
    text = f"plantdreamer {kind}\0{name}\0{token}\0{suffix}"
    return hashlib.sha256(os.fsencode(text)).hexdigest()[:8]


def _shortened(name: str, room: int) -> str:
    """``name`` cut (by characters) to at most ``room`` bytes, keeping at least one."""
    while len(os.fsencode(name)) > max(room, 1) and len(name) > 1:
        name = name[:-1]
    return name


def temporary_target(entry: str) -> str | None:
    """The target's name that the temporary ``entry`` carries (shortened when the target's
    is long: see ``temporary_name``), or None when ``entry`` is no temporary of ours."""
    if not is_temporary(entry):
        return None
    found = _FORM.fullmatch(entry)
    assert found is not None
    return found["name"]


def is_temporary_of(entry: str, target: str, limit: int = NAME_MAX) -> bool:
    """Whether ``entry`` is a temporary of ours for the target name ``target`` (a long name
    is carried shortened, in a temporary name as long as ``limit`` allows)."""
    carried = temporary_target(entry)
    if carried is None:
        return False
    return carried == target or (target.startswith(carried) and len(os.fsencode(entry)) > limit - 4)
