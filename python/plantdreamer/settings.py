"""How a config dataclass field describes itself, so one definition is the default, the
serialised value and the command-line option.

A field made with ``setting(default, "help")`` becomes a CLI option of every command built
from its dataclass (``plantdreamer.cli.options``); a plain field stays internal. Nested
config dataclasses are fields with ``metadata=option_prefix(prefix)``: their settings become
options named ``--<prefix>-<name>``. This module imports nothing heavy, so the CLI can read it at start-up.
"""

from __future__ import annotations

import dataclasses
import numbers
import types
import typing
from collections.abc import Sequence
from typing import Any

HELP = "help"  # the option's help text; its presence makes the field an option
CHOICES = "choices"  # allowed values (click.Choice)
RANGE = "range"  # (min, max) inclusive, for ints (click.IntRange)
OPTION = "option"  # the option's name when it is not --<prefix>-<field-name>
DEFAULT_TEXT = "default_text"  # shown as the default when the value is decided at run time
PREFIX = "prefix"  # on a nested config field: the prefix of its options ("" for none)


def setting(
    default: Any,
    help: str,
    *,
    choices: Sequence[str] | None = None,
    range: tuple[int, int] | None = None,
    option: str | None = None,
    default_text: str | None = None,
) -> Any:
    """A dataclass field that is also a command-line option (see the module docstring)."""
    meta: dict[str, Any] = {HELP: help}
    if choices is not None:
        meta[CHOICES] = tuple(choices)
    if range is not None:
        meta[RANGE] = range
    if option is not None:
        meta[OPTION] = option
    if default_text is not None:
        meta[DEFAULT_TEXT] = default_text
    return dataclasses.field(default=default, metadata=meta)


def option_prefix(prefix: str) -> dict[str, str]:
    """Metadata of a field holding a nested config: its settings become options
    ``--<prefix>-<name>`` ("" for no prefix)."""
    return {PREFIX: prefix}


def check_choices(config: Any) -> None:
    """ValueError naming the first field whose value is not one of its ``choices``."""
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            check_choices(value)
        elif CHOICES in f.metadata and value not in f.metadata[CHOICES]:
            allowed = ", ".join(f.metadata[CHOICES])
            raise ValueError(f"{f.name.replace('_', ' ')} must be one of {allowed}, got {value!r}")


def check_types(config: Any, prefix: str = "") -> None:
    """ValueError naming the first field whose value is not of its annotated type.

    A config built from a file or ``--set`` can hold any TOML value (a list where a path
    belongs); this refuses it when the config is checked, before any run starts.
    """
    hints = typing.get_type_hints(type(config))
    for f in dataclasses.fields(config):
        value, name = getattr(config, f.name), f"{prefix}{f.name}"
        expected = hints[f.name]
        if dataclasses.is_dataclass(expected):
            if type(value) is not expected:
                raise ValueError(f"{name} must be a table of settings, got {value!r}")
            check_types(value, f"{name}.")
        elif not _has_type(value, expected):
            raise ValueError(f"{name} must be {_type_text(expected)}, got {value!r}")


def _has_type(value: Any, expected: Any) -> bool:
    args = typing.get_args(expected)
    if isinstance(expected, types.UnionType) or typing.get_origin(expected) is typing.Union:
        return any(_has_type(value, a) for a in args)
    if expected is type(None):
        return value is None
    if expected is bool:
        return isinstance(value, bool)
    if expected is int:
        return isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if expected is float:
        return isinstance(value, numbers.Real) and not isinstance(value, bool)
    if typing.get_origin(expected) is tuple:
        return (
            isinstance(value, tuple)
            and len(value) == len(args)
            and all(_has_type(v, a) for v, a in zip(value, args, strict=True))
        )
    return isinstance(value, expected)


def _type_text(expected: Any) -> str:
    args = typing.get_args(expected)
    if isinstance(expected, types.UnionType) or typing.get_origin(expected) is typing.Union:
        return " or ".join(_type_text(a) for a in args)
    if typing.get_origin(expected) is tuple:
        return f"a list of {len(args)} numbers"
    names = {int: "an integer", float: "a number", str: "a string", bool: "true or false"}
    return names.get(expected, "none" if expected is type(None) else expected.__name__)
