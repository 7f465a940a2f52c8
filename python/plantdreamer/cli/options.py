"""Command-line options built from config dataclasses (see ``plantdreamer.settings``).

``config_options(GenerateConfig)`` adds one click option per setting, sections included,
named by the setting's one name, with the field's default, choices, range and help;
``options_to_settings`` turns the parsed values back into ``{name: value}``. A new setting is
one field: no edit here.
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
            command = click.option(old, _old_param(old), type=kind, hidden=True)(command)
        return command

    return decorate


def apply_old_names(values: dict[str, Any], aliases: dict[str, str]) -> set[str]:
    """Consumes the ``old_names`` options from ``values``: each one typed replaces its
    setting's value. Returns the settings' parameters so given."""
    given = set()
    for old, name in aliases.items():
        value = values.pop(_old_param(old))
        if value is not None:
            values[name.replace("-", "_")] = value
            given.add(name.replace("-", "_"))
    return given


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
