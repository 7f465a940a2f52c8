"""The Python API's errors in Python's words.

The checks below the API are shared with the command line, and their messages name its
options (``pass --overwrite to replace it``, ``change --split or --split-seed``). Inside
``python_words()`` an error on its way to the caller has each option named as the API's
keyword instead: a flag as the call that turns it on (``--overwrite`` ->
``overwrite=True``, ``--resume DIR`` -> ``resume=True``), any other option by its keyword
(``--split`` -> ``split``, ``--eval-views`` -> ``eval_views``), ``--set NAME=VALUE`` as a
keyword (``NAME=VALUE``), and an option only a command has with its command
(``plantdreamer dataset --dry-run``). The error keeps its type and attributes; only its message
changes. Commands (``plantdreamer lora train``) and ``--help`` are left as they are.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from contextlib import contextmanager

from plantdreamer.errors import PlantDreamerError

# The API's flags, as the command line spells them: named as the call that sets them.
FLAGS = frozenset({"overwrite", "resume", "redo-changed", "allow-empty-split", "quiet"})
# Options only a command has: named with their command.
COMMAND_ONLY = {"dry-run": "`plantdreamer dataset --dry-run`",
                "print-config": "`plantdreamer generate --print-config`"}  # fmt: skip
# An option as messages write it; not inside a word, a path or a quoted command.
_OPTION = re.compile(r"(?<![\w/.-])--([a-z][a-z0-9-]*)(?:(?<=--resume) /[^\s,;)]*)?")
_SET = re.compile(r"(?<![\w/.-])--set ([a-z_][a-z0-9_-]*=)")
_COMMAND = re.compile(r"`plantdreamer [^`]*`")


def in_python_words(message: str) -> str:
    """``message`` with the command line's options named as the API's keywords."""
    kept: list[str] = []

    def keep(match: re.Match[str]) -> str:
        kept.append(match.group(0))
        return f"\0{len(kept) - 1}\0"

    text = _COMMAND.sub(keep, message)
    text = _SET.sub(lambda m: m.group(1).replace("-", "_"), text)
    text = _OPTION.sub(_keyword, text)
    return re.sub(r"\0(\d+)\0", lambda m: kept[int(m.group(1))], text)


def _keyword(match: re.Match[str]) -> str:
    name = match.group(1)
    if name == "help":
        return match.group(0)
    if name in COMMAND_ONLY:
        return COMMAND_ONLY[name]
    return f"{name.replace('-', '_')}=True" if name in FLAGS else name.replace("-", "_")


@contextmanager
def python_words() -> Iterator[None]:
    """Errors of the package raised in the block reach the caller in Python's words."""
    try:
        yield
    except PlantDreamerError as exc:
        if exc.args and isinstance(exc.args[0], str):
            exc.args = (in_python_words(exc.args[0]), *exc.args[1:])
        raise
