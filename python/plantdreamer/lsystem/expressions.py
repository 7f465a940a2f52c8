"""Arithmetic expressions in L-System productions, e.g. ``l*0.9`` or ``rand(100, 160)``.

Expressions use Python syntax restricted to numbers, names, arithmetic, comparisons,
``and``/``or``/``not``, conditional expressions and calls of whitelisted functions. They are
checked once when a grammar is built (so a typo fails early with InputError) and compiled to
code objects that run with no builtins.
"""

from __future__ import annotations

import ast
import math
from collections.abc import Callable, Mapping
from types import CodeType
from typing import Any

from plantdreamer.errors import InputError

_ALLOWED_NODES = (
    ast.Expression,
    ast.Constant,
    ast.Name,
    ast.Load,
    ast.BinOp,
    ast.UnaryOp,
    ast.BoolOp,
    ast.Compare,
    ast.IfExp,
    ast.Call,
    ast.Add,
    ast.Sub,
    ast.Mult,
    ast.Div,
    ast.FloorDiv,
    ast.Mod,
    ast.Pow,
    ast.USub,
    ast.UAdd,
    ast.Not,
    ast.And,
    ast.Or,
    ast.Eq,
    ast.NotEq,
    ast.Lt,
    ast.LtE,
    ast.Gt,
    ast.GtE,
)

# Deterministic functions every grammar may call; `rand` is bound per derivation to its RNG.
MATH_FUNCTIONS: dict[str, Callable[..., float]] = {
    "sqrt": math.sqrt,
    "sin": lambda deg: math.sin(math.radians(deg)),
    "cos": lambda deg: math.cos(math.radians(deg)),
    "exp": math.exp,
    "floor": math.floor,
    "min": min,
    "max": max,
    "abs": abs,
}
RANDOM_FUNCTIONS = ("rand", "randint", "normal")


class Expression:
    """A compiled expression; ``evaluate(names)`` returns its value."""

    __slots__ = ("code", "names", "source")

    def __init__(self, source: str, known_names: set[str] | None = None) -> None:
        self.source = source.strip()
        if not self.source:
            raise InputError("empty expression")
        try:
            tree = ast.parse(self.source, mode="eval")
        except SyntaxError as exc:
            raise InputError(f"invalid expression {source!r}: {exc.msg}") from None
        names: set[str] = set()
        for node in ast.walk(tree):
            if not isinstance(node, _ALLOWED_NODES):
                raise InputError(
                    f"expression {source!r} uses {type(node).__name__}, which is not allowed"
                )
            if isinstance(node, ast.Call) and (
                not isinstance(node.func, ast.Name) or node.keywords
            ):
                raise InputError(f"expression {source!r}: only plain function calls are allowed")
            if isinstance(node, ast.Name):
                names.add(node.id)
            if isinstance(node, ast.Constant) and not isinstance(node.value, int | float):
                raise InputError(f"expression {source!r}: only numeric constants are allowed")
        if known_names is not None:
            unknown = names - known_names - set(MATH_FUNCTIONS) - set(RANDOM_FUNCTIONS)
            if unknown:
                raise InputError(
                    f"expression {source!r} uses unknown name(s) {', '.join(sorted(unknown))}"
                )
        self.names = frozenset(names)
        self.code: CodeType = compile(tree, "<lsystem>", "eval")

    def evaluate(self, names: Mapping[str, Any]) -> Any:
        try:
            return eval(self.code, {"__builtins__": {}}, names)
        except (ArithmeticError, ValueError, TypeError) as exc:
            raise InputError(f"evaluating {self.source!r} failed: {exc}") from None

    def __repr__(self) -> str:
        return f"Expression({self.source!r})"
