"""How a config dataclass describes its settings, so one definition is the default, the
serialised value, the command-line option and the key of a spec, ``--set`` and ``--resume``.

A field made with ``setting(default, "help")`` is a setting; its *name* is its option's name
without the dashes (``points``, ``densify-start``): ``--points`` on the command line,
``points = 5000`` in a spec, ``--set points=5000``. A field holding a nested config carries
``metadata=option_prefix(prefix)``: its settings are named ``<prefix>-<field>`` ("" for none).
A plain field stays internal. This module imports nothing heavy (the CLI reads it at start-up).
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import numbers
import types
import typing
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

HELP = "help"  # the option's help text; its presence makes the field a setting
CHOICES = "choices"  # allowed values (click.Choice)
RANGE = "range"  # (min, max), inclusive unless OPEN says (click.IntRange / FloatRange)
OPEN = "open"  # (low open, high open): which ends of RANGE the value may not take
OPTION = "option"  # the option's name when it is not --<prefix>-<field-name>
DEFAULT_TEXT = "default_text"  # shown as the default when the value is decided at run time
PREFIX = "prefix"  # on a nested config field: the prefix of its settings ("" for none)


def setting(
    default: Any,
    help: str,
    *,
    choices: Sequence[str] | None = None,
    range: tuple[float, float] | None = None,
    open: tuple[bool, bool] = (False, False),
    option: str | None = None,
    default_text: str | None = None,
) -> Any:
    """A dataclass field that is also a setting (see the module docstring); ``range``
    bounds a number (ends included unless ``open`` says), on the command line, in specs,
    ``--set`` and resumed records alike."""
    meta: dict[str, Any] = {HELP: help}
    if choices is not None:
        meta[CHOICES] = tuple(choices)
    if range is not None:
        meta[RANGE] = range
        meta[OPEN] = open
    if option is not None:
        meta[OPTION] = option
    if default_text is not None:
        meta[DEFAULT_TEXT] = default_text
    return dataclasses.field(default=default, metadata=meta)


def option_prefix(prefix: str) -> dict[str, str]:
    """Metadata of a field holding a nested config: ``field(default_factory=Section,
    metadata=option_prefix("densify"))`` names its settings ``densify-<name>``."""
    return {PREFIX: prefix}


@dataclasses.dataclass(frozen=True)
class Setting:
    name: str  # the one name: option without "--", spec / --set / resume key
    path: tuple[str, ...]  # field names from the top config down
    field: dataclasses.Field
    type: Any  # the field's resolved annotation
    default: Any

    @property
    def param(self) -> str:
        """The click parameter (a Python identifier)."""
        return self.name.replace("-", "_")


def walk(cls: type, path: tuple[str, ...] = (), prefix: str = "") -> Iterator[Setting]:
    """Every setting of ``cls`` and its sections, in declaration order."""
    hints = _type_hints(cls)
    for f in dataclasses.fields(cls):
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        if PREFIX in f.metadata:
            inner = f.metadata[PREFIX]
            yield from walk(type(default), (*path, f.name), _join(prefix, inner))
        elif HELP in f.metadata:
            option = f.metadata.get(OPTION) or "--" + _join(prefix, f.name)
            name = option[2:].replace("_", "-")
            yield Setting(name, (*path, f.name), f, hints[f.name], default)


@functools.cache
def _type_hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _join(prefix: str, name: str) -> str:
    return f"{prefix}-{name}" if prefix else name


def by_name(cls: type) -> dict[str, Setting]:
    return {s.name: s for s in walk(cls)}


def canonical(name: str) -> str:
    """Spec and ``--set`` keys may use ``_`` for ``-`` (TOML users write either)."""
    return name.strip().replace("_", "-")


def unknown_message(name: str, known: Sequence[str]) -> str:
    inside = [k for k in known if k.startswith(name + "-")]
    if inside:  # a section's prefix (lr, cameras, densify, cull): name its settings
        return f"{name!r} is not one setting; give each by name: {', '.join(inside)}"
    close = difflib.get_close_matches(name, known, n=1)
    hint = f"; did you mean {close[0]!r}?" if close else " (see `plantdreamer generate --help`)"
    return f"unknown setting {name!r}{hint}"


def names_to_tree(cls: type, values: Mapping[str, Any]) -> dict[str, Any]:
    """``{name: value}`` as a dict nested like ``cls``'s fields; KeyError-free: an unknown
    name is a ValueError naming the closest known one."""
    known = by_name(cls)
    tree: dict[str, Any] = {}
    for key, value in values.items():
        name = canonical(key)
        if name not in known:
            raise ValueError(unknown_message(name, list(known)))
        node = tree
        path = known[name].path
        for part in path[:-1]:
            node = node.setdefault(part, {})
        node[path[-1]] = list(value) if isinstance(value, tuple) else value
    return tree


def value_of(config: Any, name: str) -> Any:
    """The value of the setting ``name`` in ``config``."""
    known = by_name(type(config))
    if canonical(name) not in known:
        raise ValueError(unknown_message(canonical(name), list(known)))
    return value_at(config, known[canonical(name)].path)


def value_at(config: Any, path: tuple[str, ...]) -> Any:
    value = config
    for part in path:
        value = getattr(value, part)
    return value


def check_choices(config: Any) -> None:
    """ValueError naming the first setting whose value is not one of its ``choices`` or is
    outside its ``range`` (the same limits the command line applies)."""
    for s in walk(type(config)):
        value = value_at(config, s.path)
        meta = s.field.metadata
        if CHOICES in meta and value not in meta[CHOICES]:
            allowed = ", ".join(meta[CHOICES])
            raise ValueError(f"{s.name.replace('-', ' ')} must be one of {allowed}, got {value!r}")
        if RANGE in meta and value is not None and not in_range(value, meta):
            raise ValueError(f"{s.name} must be in {range_text(meta)}, got {value!r}")


def in_range(value: Any, meta: Mapping[str, Any]) -> bool:
    """Whether a number lies in a setting's ``range`` (with its ``open`` ends)."""
    (low, high), (low_open, high_open) = meta[RANGE], meta.get(OPEN, (False, False))
    above = value > low if low_open else value >= low
    below = value < high if high_open else value <= high
    return above and below


def range_text(meta: Mapping[str, Any]) -> str:
    """``0..3`` for a closed range, interval notation (``(0, 1)``, ``[0, 1e+06]``) else."""
    (low, high), (low_open, high_open) = meta[RANGE], meta.get(OPEN, (False, False))
    if isinstance(low, int) and isinstance(high, int) and not (low_open or high_open):
        return f"{low}..{high}"
    return f"{'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"


def check_types(config: Any) -> None:
    """ValueError naming the first setting whose value is not of its annotated type, or
    is a number that is not finite: the one check of a setting's number (3.7 points is an
    error, not 3; NaN is no grey level).

    A config built from a file or ``--set`` can hold any TOML value (a list where a path
    belongs); this refuses it when the config is checked, before any run starts.
    """
    for s in walk(type(config)):
        value = value_at(config, s.path)
        if not _has_type(value, s.type):
            raise ValueError(f"{s.name} must be {_type_text(s.type)}, got {value!r}")
        numbers_in = value if isinstance(value, tuple) else (value,)
        if any(_is_real(v) and not math.isfinite(v) for v in numbers_in):
            raise ValueError(f"{s.name} must be finite, got {value!r}")


def _is_real(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


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
        return _is_real(value)
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
