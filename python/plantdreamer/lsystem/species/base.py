"""What a species module provides: its grammar, turtle settings and organ shapes."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

from plantdreamer.lsystem.engine import LSystem, Rule
from plantdreamer.lsystem.organs import LeafShape, PotShape
from plantdreamer.lsystem.turtle import TurtleConfig


@dataclass(frozen=True)
class Species:
    """A plant species as an L-System plus the shapes of its organs.

    Leaf modules in the grammar (the keys of ``leaves``) take ``(length [, tone])``: the blade
    length in metres and a 0..1 tone (0 mature colour, 1 young and lighter).
    ``height_range`` and ``leaf_range`` document what the species produces over seeds (plant
    height above the soil in metres, number of leaf instances); tests check them.
    """

    name: str
    summary: str
    axiom: str
    rules: tuple[Rule, ...]
    iterations: int
    turtle: TurtleConfig
    leaves: Mapping[str, LeafShape]
    constants: Mapping[str, Any] = field(default_factory=dict)
    stem_sides: int = 8
    stem_color: tuple[float, float, float] = (0.36, 0.52, 0.20)
    stem_base_color: tuple[float, float, float] | None = None
    pot: PotShape = field(default_factory=PotShape)
    height_range: tuple[float, float] = (0.0, 1.0)
    leaf_range: tuple[int, int] = (0, 10_000)
    prompt_name: str | None = None  # the plant's name in prompts, if not ``name``

    @property
    def plant_name(self) -> str:
        """What the prompts call this plant: ``bean-released`` is a bean."""
        return self.prompt_name or self.name

    @cached_property
    def lsystem(self) -> LSystem:
        # Rules are compiled in place; copy them so a Species can be built twice.
        rules = [Rule(r.predecessor, r.successor, r.condition, r.probability) for r in self.rules]
        return LSystem(self.axiom, rules, self.constants)
