"""Growth stages: a plant earlier in its development, with the same leaves.

A stage ``growth`` in (0, 1] is a time ``t = growth x N`` on the species' derivation of
``N`` steps. The plant at ``t`` is the full-grown plant's derivation (the same string, the
same random draws: no fewer rewriting steps) in which every module carries its birth, the
step that wrote it (``LSystem.derive_timed``):

- a stem point exists once the ``F`` that drew it is born (``birth <= t``); a stem chain
  is drawn up to its last point born (where a grammar lengthens an internode by adding
  ``F`` inside it, as the authors' bean does, the points above it are drawn with it, so
  nothing hangs in the air);
- an organ exists once born, and a leaf is built when its blade is then at least
  ``plant.MIN_LEAF_LENGTH`` long;
- an organ of age ``a = t - birth`` has its full-grown size times
  ``g(a) / g(N - birth)`` with ``g(a) = 1 - exp(-(a + AGE_OFFSET) / AGE_SCALE)``, the
  saturating curve the species' own grammars size their organs with (bean's leaflet:
  ``1 - exp(-(age + 0.4) / 1.6)``); stem radii likewise, by their points' births.

So a leaf keeps its instance id (that of the full-grown plant) at every stage it exists
at, its insertion point (the blade's base, where the turtle met its symbol) never moves,
and its size only grows with ``t``. Deriving fewer steps instead would not: the grammars
size each organ by its age at the last step (``N - i``), draw their random numbers in
string order (a node's angles would change with the steps), and a leaf's id is its place
in the string, which later branches change. The full stage (``growth`` 1) is the plant
made without a stage, to the byte (``tests/test_growth.py``).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, replace

import numpy as np

from plantdreamer.errors import InputError
from plantdreamer.lsystem.turtle import Skeleton

FULL_GROWN = 1.0  # the growth stage of the full-grown plant (the default)
AGE_OFFSET = 0.5  # derivation steps: a just-born organ's age on the growth curve
AGE_SCALE = 2.0  # derivation steps in which an organ grows 63% of the way to its size


def check_growth(growth: float) -> None:
    """InputError unless ``growth`` is a number in (0, 1]."""
    number = isinstance(growth, numbers.Real) and not isinstance(growth, bool)
    if not (number and math.isfinite(growth) and 0.0 < growth <= FULL_GROWN):
        raise InputError(f"growth must be a stage in (0, 1] (1: full-grown), got {growth!r}")


def size_curve(age: float) -> float:
    """``g``: the share of its final size an organ of ``age`` steps has grown to."""
    return 1.0 - math.exp(-(age + AGE_OFFSET) / AGE_SCALE)


@dataclass(frozen=True)
class Stage:
    """A growth stage of a species of ``steps`` derivation steps."""

    growth: float
    steps: int

    @property
    def time(self) -> float:
        """The stage in derivation steps."""
        return self.growth * self.steps

    @property
    def full(self) -> bool:
        return self.growth == FULL_GROWN

    def has(self, birth: int) -> bool:
        """Whether a module born at step ``birth`` exists at this stage."""
        return self.full or birth <= self.time

    def scale(self, birth: int) -> float:
        """The size of an organ born at ``birth`` against its full-grown size (1 at the
        full stage; 0 before it is born)."""
        if self.full:
            return 1.0
        if not self.has(birth):
            return 0.0
        return size_curve(self.time - birth) / size_curve(self.steps - birth)

    def emerged(self, birth: int, full_length: float, min_length: float) -> float:
        """The earliest stage at which a leaf born at ``birth`` whose full-grown blade is
        ``full_length`` long is built (its blade at least ``min_length``): the stage
        that it is born at, or later, when its blade reaches ``min_length`` (to float
        rounding)."""
        need = min_length / full_length * size_curve(self.steps - birth)
        age = 0.0 if need <= size_curve(0.0) else -AGE_SCALE * math.log1p(-need) - AGE_OFFSET
        return min(FULL_GROWN, max(0.0, birth + age) / self.steps)

    def skeleton(self, skeleton: Skeleton) -> Skeleton:
        """The skeleton at this stage: each chain up to its last point born (radii
        scaled by their points' ages, a point not yet born as just born; a chain not begun
        keeps no point, so chain indices stay those of the full plant), the organs born.
        The full stage is ``skeleton`` itself."""
        if self.full:
            return skeleton
        chains = []
        for chain in skeleton.chains:
            born = np.flatnonzero(chain.births <= self.time)
            upto = int(born[-1]) + 1 if len(born) else 0
            scale = np.array([self._radius_scale(int(b)) for b in chain.births[:upto]])
            chains.append(
                replace(
                    chain,
                    points=chain.points[:upto],
                    radii=chain.radii[:upto] * scale,
                    births=chain.births[:upto],
                )
            )
        organs = [o for o in skeleton.organs if self.has(o.birth)]
        return Skeleton(chains, organs)

    def _radius_scale(self, birth: int) -> float:
        age = max(self.time - birth, 0.0)
        return size_curve(age) / size_curve(self.steps - birth)
