"""A stochastic, parametric, context-free L-System (Prusinkiewicz & Lindenmayer, ABOP ch. 1-2).

A *module* is a one-character symbol with numeric parameters, written ``F(0.03)`` or ``A(n+1, w)``.
A production ``Rule("A(n, w)", "F(n) [+(30) B(w)] A(n+1, w*0.9)", condition="n < 7")``
rewrites every ``A`` with two parameters whose condition holds. Several rules for the same
symbol whose conditions hold are chosen between at random with their relative
``probability`` (a stochastic L-System). Expressions may call ``rand(a, b)`` (uniform),
``randint(a, b)`` (integer in [a, b]) and ``normal(mean, sd)``; every draw comes from one
seeded ``numpy.random.Generator`` in string order, so a seed fixes the whole derivation.

Whitespace between modules is ignored. ``[`` and ``]`` never take parameters.

``derive_timed`` also gives each module of the result its *birth*: the rewriting step that
produced it (0 for the axiom's modules, 1 for those the first step wrote, ...). A module no
rule rewrites keeps its birth; what a rule writes is born at that step. The plant's growth
stages (``plant.py``) age its organs by it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from plantdreamer.errors import InputError
from plantdreamer.lsystem.expressions import MATH_FUNCTIONS, Expression

# Hard limit on the string length, so a runaway grammar fails clearly instead of eating memory.
MAX_MODULES = 2_000_000


@dataclass(frozen=True, slots=True)
class Module:
    """One symbol of a derived string with its evaluated parameters."""

    symbol: str
    params: tuple[float, ...] = ()

    def __str__(self) -> str:
        if not self.params:
            return self.symbol
        return f"{self.symbol}({','.join(f'{p:g}' for p in self.params)})"


@dataclass(frozen=True, slots=True)
class _Template:
    """A successor module whose parameters are still expressions."""

    symbol: str
    args: tuple[Expression, ...]


def _split_modules(text: str) -> list[tuple[str, list[str]]]:
    """``"F(1) [+(a,b)]"`` -> ``[("F", ["1"]), ("[", []), ("+", ["a", "b"]), ("]", [])]``."""
    out: list[tuple[str, list[str]]] = []
    i, n = 0, len(text)
    while i < n:
        ch = text[i]
        if ch.isspace():
            i += 1
            continue
        if ch in "(),":
            raise InputError(f"unexpected {ch!r} at position {i} in {text!r}")
        i += 1
        args: list[str] = []
        if i < n and text[i] == "(":
            depth, start = 1, i + 1
            j = start
            while j < n and depth:
                if text[j] == "(":
                    depth += 1
                elif text[j] == ")":
                    depth -= 1
                elif text[j] == "," and depth == 1:
                    args.append(text[start:j])
                    start = j + 1
                j += 1
            if depth:
                raise InputError(f"unbalanced parentheses after {ch!r} in {text!r}")
            args.append(text[start : j - 1])
            i = j
        out.append((ch, args))
    return out


@dataclass
class Rule:
    """A production ``predecessor : condition -> successor`` chosen with ``probability``.

    ``predecessor`` is a symbol with formal parameter names, e.g. ``"A(n, w)"``.
    """

    predecessor: str
    successor: str
    condition: str | None = None
    probability: float = 1.0
    symbol: str = field(init=False, repr=False, default="")
    formals: tuple[str, ...] = field(init=False, repr=False, default=())
    _successor: tuple[_Template, ...] = field(init=False, repr=False, default=())
    _condition: Expression | None = field(init=False, repr=False, default=None)

    def compile(self, constants: Mapping[str, Any]) -> None:
        """Parses the rule; raises InputError naming the problem."""
        parts = _split_modules(self.predecessor)
        if len(parts) != 1:
            raise InputError(f"predecessor must be one module, got {self.predecessor!r}")
        self.symbol, formals = parts[0]
        self.formals = tuple(f.strip() for f in formals)
        for name in self.formals:
            if not name.isidentifier():
                raise InputError(f"formal parameter {name!r} in {self.predecessor!r}")
        if not (self.probability > 0 and np.isfinite(self.probability)):
            raise InputError(f"rule {self.predecessor!r}: probability must be > 0")
        known = set(self.formals) | set(constants)
        self._condition = Expression(self.condition, known) if self.condition else None
        self._successor = tuple(
            _Template(sym, tuple(Expression(a, known) for a in args))
            for sym, args in _split_modules(self.successor)
        )


class LSystem:
    """An axiom, rules and named constants; ``derive`` rewrites the axiom ``n`` times."""

    def __init__(
        self, axiom: str, rules: Sequence[Rule], constants: Mapping[str, Any] | None = None
    ) -> None:
        self.constants = dict(constants or {})
        self.rules: dict[tuple[str, int], list[Rule]] = {}
        for rule in rules:
            rule.compile(self.constants)
            self.rules.setdefault((rule.symbol, len(rule.formals)), []).append(rule)
        self._axiom = tuple(
            _Template(sym, tuple(Expression(a, set(self.constants)) for a in args))
            for sym, args in _split_modules(axiom)
        )

    def derive(self, iterations: int, rng: np.random.Generator) -> list[Module]:
        """The string after ``iterations`` parallel rewriting steps."""
        return self.derive_timed(iterations, rng)[0]

    def derive_timed(
        self, iterations: int, rng: np.random.Generator
    ) -> tuple[list[Module], list[int]]:
        """The string after ``iterations`` steps and each module's birth step (the same
        string and draws as ``derive``)."""
        if iterations < 0:
            raise InputError(f"iterations must be >= 0, got {iterations}")
        env = self._environment(rng)
        string = [self._instantiate(t, env) for t in self._axiom]
        births = [0] * len(string)
        for step in range(1, iterations + 1):
            string, births = self._step(string, births, step, env, rng)
        return string, births

    def _environment(self, rng: np.random.Generator) -> dict[str, Any]:
        env: dict[str, Any] = dict(MATH_FUNCTIONS)
        env["rand"] = lambda a, b: float(rng.uniform(a, b))
        env["randint"] = lambda a, b: int(rng.integers(int(a), int(b), endpoint=True))
        env["normal"] = lambda mean, sd: float(rng.normal(mean, sd))
        env.update(self.constants)
        return env

    @staticmethod
    def _instantiate(template: _Template, names: Mapping[str, Any]) -> Module:
        params = []
        for arg in template.args:
            value = float(arg.evaluate(names))
            if not np.isfinite(value):
                raise InputError(f"{template.symbol}({arg.source}) evaluated to {value}")
            params.append(value)
        return Module(template.symbol, tuple(params))

    def _step(
        self,
        string: list[Module],
        births: list[int],
        step: int,
        env: dict[str, Any],
        rng: np.random.Generator,
    ) -> tuple[list[Module], list[int]]:
        out: list[Module] = []
        out_births: list[int] = []
        for module, birth in zip(string, births, strict=True):
            candidates = self.rules.get((module.symbol, len(module.params)))
            if not candidates:
                out.append(module)
                out_births.append(birth)
                continue
            names = env
            if candidates[0].formals:
                names = {**env, **dict(zip(candidates[0].formals, module.params, strict=True))}
            rule = self._choose(candidates, module, names, env, rng)
            if rule is None:
                out.append(module)
                out_births.append(birth)
                continue
            if rule.formals != candidates[0].formals:
                names = {**env, **dict(zip(rule.formals, module.params, strict=True))}
            out.extend(self._instantiate(t, names) for t in rule._successor)
            out_births.extend([step] * (len(out) - len(out_births)))
            if len(out) > MAX_MODULES:
                raise InputError(f"L-System string grew past {MAX_MODULES} modules")
        return out, out_births

    @staticmethod
    def _choose(
        candidates: list[Rule],
        module: Module,
        names: dict[str, Any],
        env: dict[str, Any],
        rng: np.random.Generator,
    ) -> Rule | None:
        matching = []
        for rule in candidates:
            local = names
            if rule.formals != candidates[0].formals:
                local = {**env, **dict(zip(rule.formals, module.params, strict=True))}
            if rule._condition is None or rule._condition.evaluate(local):
                matching.append(rule)
        if len(matching) <= 1:
            return matching[0] if matching else None
        weights = np.array([r.probability for r in matching])
        pick = rng.random() * weights.sum()
        index = int(np.searchsorted(np.cumsum(weights), pick, side="right"))
        return matching[min(index, len(matching) - 1)]


def format_string(modules: Sequence[Module]) -> str:
    """The derived string in the usual notation, for debugging and tests."""
    return " ".join(str(m) for m in modules)
