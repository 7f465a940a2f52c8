"""Command-line options built from config dataclasses (see ``plantdreamer.settings``).

``config_options(GenerateConfig)`` adds one click option per ``setting(...)`` field, nested
configs included, with the field's default, choices and help; ``config_from_options`` turns
the parsed values back into the config. A new setting is one field: no edit here.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Callable, Collection, Iterator
from typing import Any, TypeVar

import click

from plantdreamer import settings

F = TypeVar("F", bound=Callable[..., Any])
_SEP = "__"  # joins a nested field's path into one click parameter name


@dataclasses.dataclass(frozen=True)
class _Option:
    path: tuple[str, ...]  # field names from the top config down
    field: dataclasses.Field
    type: Any  # the field's resolved annotation
    default: Any
    option: str

    @property
    def param(self) -> str:
        return _SEP.join(self.path)


def _walk(cls: type, path: tuple[str, ...] = (), prefix: str = "") -> Iterator[_Option]:
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        if settings.PREFIX in f.metadata:
            inner = f.metadata[settings.PREFIX]
            yield from _walk(type(default), (*path, f.name), _join(prefix, inner))
        elif settings.HELP in f.metadata:
            option = f.metadata.get(settings.OPTION) or "--" + _join(prefix, f.name)
            yield _Option((*path, f.name), f, hints[f.name], default, option.replace("_", "-"))


def _join(prefix: str, name: str) -> str:
    return f"{prefix}-{name}" if prefix else name


def _click_type(opt: _Option) -> Any:
    meta = opt.field.metadata
    if settings.CHOICES in meta:
        return click.Choice(list(meta[settings.CHOICES]))
    if settings.RANGE in meta:
        return click.IntRange(*meta[settings.RANGE])
    args = [a for a in typing.get_args(opt.type) if a is not type(None)]
    base = args[0] if args else opt.type  # X | None -> X
    if base not in (int, float, str, bool):
        raise TypeError(f"setting {opt.param}: no command-line type for {opt.type!r}")
    return base


def _option(opt: _Option) -> Callable[[F], F]:
    meta = opt.field.metadata
    text = meta.get(settings.DEFAULT_TEXT)
    kind = _click_type(opt)
    if kind is bool:
        name = opt.option[2:]
        return click.option(
            f"--{name}/--no-{name}", opt.param, default=opt.default, help=meta[settings.HELP],
            show_default=True,
        )  # fmt: skip
    return click.option(
        opt.option,
        opt.param,
        type=kind,
        default=opt.default,
        help=meta[settings.HELP],
        show_default=text if text is not None else opt.default is not None,
    )


def config_options(cls: type, only: Collection[str] | None = None) -> Callable[[F], F]:
    """A decorator adding ``cls``'s settings as options (``only``: these option names)."""
    opts = [o for o in _walk(cls) if only is None or o.option in only]
    if only is not None and len(opts) != len(only):
        missing = set(only) - {o.option for o in opts}
        raise ValueError(f"{cls.__name__} has no settings {sorted(missing)}")

    def decorate(command: F) -> F:
        for opt in reversed(opts):  # click lists options in decoration order, bottom up
            command = _option(opt)(command)
        return command

    return decorate


def config_from_options(cls: type, values: dict[str, Any]) -> Any:
    """``cls`` with the given option values (as named by ``config_options``), the rest default.

    Consumes the values it uses from ``values``.
    """
    return _build(cls, options_tree(cls, values))


def options_tree(cls: type, values: dict[str, Any]) -> dict[str, Any]:
    """The given option values as a dict nested like ``cls``'s fields; consumes them."""
    tree: dict[str, Any] = {}
    for opt in _walk(cls):
        if opt.param in values:
            node = tree
            for name in opt.path[:-1]:
                node = node.setdefault(name, {})
            node[opt.path[-1]] = values.pop(opt.param)
    return tree


def given_on_command_line(values: dict[str, Any]) -> dict[str, Any]:
    """The values of the current click command that were not left at their defaults."""
    ctx = click.get_current_context()
    return {
        name: value
        for name, value in values.items()
        if ctx.get_parameter_source(name) != click.core.ParameterSource.DEFAULT
    }


def _build(cls: type, tree: dict[str, Any]) -> Any:
    hints = typing.get_type_hints(cls)
    kwargs = {
        name: _build(hints[name], value) if isinstance(value, dict) else value
        for name, value in tree.items()
    }
    return cls(**kwargs)
