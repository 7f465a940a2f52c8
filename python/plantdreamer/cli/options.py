"""Command-line options built from config dataclasses (see ``plantdreamer.settings``).

``config_options(GenerateConfig)`` adds one click option per setting, sections included,
named by the setting's one name, with the field's default, choices, range and help;
``options_to_settings`` turns the parsed values back into ``{name: value}``. A new setting is
one field: no edit here. An option renamed keeps its earlier name as a hidden option
(``old_names``, ``hidden_old_name``); ``apply_old_names`` moves its value onto the new name and
refuses the two given with different values (``one_value``), so neither silently wins.
"""

from __future__ import annotations

import typing
from collections.abc import Callable, Collection
from typing import Any, TypeVar

import click

from plantdreamer import settings

F = TypeVar("F", bound=Callable[..., Any])


def _click_type(s: settings.Setting) -> Any:
    meta = s.field.metadata
    if settings.CHOICES in meta:
        return click.Choice(list(meta[settings.CHOICES]))
    if settings.RANGE in meta and s.type in (int, int | None):
        return click.IntRange(*meta[settings.RANGE])
    # A number's range otherwise is the config's check: one `error:` line, as from a spec.
    if typing.get_origin(s.type) is tuple:
        return typing.get_args(s.type)
    args = [a for a in typing.get_args(s.type) if a is not type(None)]
    base = args[0] if args else s.type  # X | None -> X
    if typing.get_origin(base) is tuple:  # a range left to the run when not given
        return typing.get_args(base)
    if base not in (int, float, str, bool):
        raise TypeError(f"setting {s.name}: no command-line type for {s.type!r}")
    return base


def _option(s: settings.Setting, with_default: bool, note: str) -> Callable[[F], F]:
    meta = s.field.metadata
    text = meta.get(settings.DEFAULT_TEXT)
    kind = _click_type(s)
    default = s.default if with_default else None
    help_text = meta[settings.HELP] + note
    shown = text if text is not None else s.default is not None
    if kind is bool:
        return click.option(
            f"--{s.name}/--no-{s.name}", s.param, default=default, help=help_text,
            show_default=shown if with_default else False,
        )  # fmt: skip
    return click.option(
        f"--{s.name}",
        s.param,
        type=kind,
        default=default,
        help=help_text,
        show_default=shown if with_default else False,
    )


def config_options(
    cls: type, only: Collection[str] | None = None, *, with_defaults: bool = True, note: str = ""
) -> Callable[[F], F]:
    """A decorator adding ``cls``'s settings as options (``only``: these names).

    ``with_defaults=False`` leaves every option at None unless given (settings that apply
    over others, as `dataset`'s do); ``note`` is appended to each help text."""
    opts = [s for s in settings.walk(cls) if only is None or s.name in only]
    if only is not None and len(opts) != len(only):
        missing = set(only) - {s.name for s in opts}
        raise ValueError(f"{cls.__name__} has no settings {sorted(missing)}")

    def decorate(command: F) -> F:
        for s in reversed(opts):  # click lists options in decoration order, bottom up
            command = _option(s, with_defaults, note)(command)
        return command

    return decorate


def options_to_settings(cls: type, values: dict[str, Any]) -> dict[str, Any]:
    """The option values (click parameter names) that are settings of ``cls``, by their one
    name; consumes them from ``values``."""
    return {s.name: values.pop(s.param) for s in settings.walk(cls) if s.param in values}


def config_from_options(cls: type, values: dict[str, Any]) -> Any:
    """``cls`` with the given option values (as named by ``config_options``), the rest default.

    Consumes the values it uses from ``values``."""
    return cls.from_settings(options_to_settings(cls, values))  # type: ignore[attr-defined]


def old_names(cls: type, aliases: dict[str, str]) -> Callable[[F], F]:
    """Hidden options under settings' earlier names (``{"--views": "eval-views"}``), so
    old command lines keep working; ``apply_old_names`` moves a typed one onto its setting."""
    known = settings.by_name(cls)

    def decorate(command: F) -> F:
        for old, name in aliases.items():
            s = known[name]
            kind = _click_type(s)
            command = click.option(
                old, _old_param(old), type=kind, hidden=True, help=f"Earlier name of --{name}."
            )(command)
        return command

    return decorate


def hidden_old_name(old: str, new: str, **kwargs: Any) -> Callable[[F], F]:
    """A hidden option under an option's earlier name (``--output`` for ``--out``), of the
    same type as ``new``; ``apply_old_names(values, {old: new})`` moves a typed one onto it."""
    return click.option(old, _old_param(old), hidden=True, help=f"Earlier name of {new}.", **kwargs)


def apply_old_names(
    values: dict[str, Any], aliases: dict[str, str], ctx: click.Context | None = None
) -> set[str]:
    """Consumes the ``old_names`` options from ``values``: each one typed replaces its
    setting's value, and one typed beside its new name with another value is refused
    (``one_value``). Returns the settings' parameters so given."""
    typed = typed_options(ctx)
    given = set()
    for old, name in aliases.items():
        value = values.pop(_old_param(old))
        if value is None:
            continue
        param = name.lstrip("-").replace("-", "_")
        new = "--" + name.lstrip("-")
        if param in typed:
            one_value(old, value, new, values[param])
        values[param] = value
        given.add(param)
    return given


def one_value(old: str, old_value: Any, new: str, new_value: Any) -> None:
    """An earlier option name given beside its new name: the same value is the same request;
    another is refused in one line (neither silently wins)."""
    if old_value != new_value:
        from plantdreamer.errors import InputError

        raise InputError(
            f"{old} (the earlier name of {new}) gives {_shown(old_value)} and {new} gives "
            f"{_shown(new_value)}; give {new} once"
        )


def _shown(value: Any) -> str:
    if isinstance(value, (list, tuple)):
        return ",".join(map(str, value))
    return str(value)


def _old_param(old: str) -> str:
    return "old_" + old.lstrip("-").replace("-", "_")


def typed_options(ctx: click.Context | None = None) -> set[str]:
    """The parameters (click names) of ``ctx`` (default: the current command) that the
    user typed, on the command line or in the environment, not left at their defaults:
    the one test of "was this option given"."""
    ctx = ctx or click.get_current_context()
    typed = (click.core.ParameterSource.COMMANDLINE, click.core.ParameterSource.ENVIRONMENT)
    return {name for name in ctx.params if ctx.get_parameter_source(name) in typed}


def given_on_command_line(values: dict[str, Any]) -> dict[str, Any]:
    """The ``values`` of the current command's options that the user typed."""
    typed = typed_options()
    return {name: value for name, value in values.items() if name in typed}
