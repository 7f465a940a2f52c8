"""A set of plants by seed, in one grammar wherever it is typed: ``generate --seeds``,
``dataset --seeds`` and a spec's ``seeds``: ``0-7``, ``0,3,5`` or both (``0-3,8``), in the
order given. A spec may also give a TOML list (``seeds = [0, 7]``); the earlier
``--count N --seed-start S`` (a spec's ``count`` / ``seed-start``) is ``S-(S+N-1)``.
Torch-free: the CLI parses it at start-up."""

from __future__ import annotations

from typing import Any

from plantdreamer.errors import InputError

MAX_SEED = 2**32 - 1  # a plant's seed (GenerateConfig checks the same range)
MAX_SEEDS = 1_000_000  # plants in one set, counted before any list is made


def parse_seeds(text: str, most: int = MAX_SEEDS, what: str = "--seeds") -> list[int]:
    """The seeds ``text`` names; reversed ranges, duplicates, seeds outside 0..MAX_SEED and
    more than ``most`` seeds are refused (InputError naming ``what``)."""
    parts: list[range] = []
    try:
        for part in (p.strip() for p in text.split(",") if p.strip()):
            low, dash, high = part.partition("-")
            if dash and int(low) > int(high):
                raise InputError(
                    f"{what}: {part} is a reversed range; write {high.strip()}-{low.strip()}"
                )
            parts.append(
                range(int(low), int(high) + 1) if dash else range(int(part), int(part) + 1)
            )
    except ValueError:
        raise InputError(
            f"{what} takes numbers and ranges like 0-7 or 0,3,5, got {text!r}"
        ) from None
    if not parts:
        raise InputError(f"{what} is empty; give at least one seed")
    count = sum(len(r) for r in parts)
    if count > most:
        raise TooManySeeds(f"{what} {text} names {count} plants; at most {most} at once", count)
    if any(r.stop - 1 > MAX_SEED for r in parts):
        raise InputError(f"{what}: seeds must be in 0..{MAX_SEED}, got {text!r}")
    seeds = [seed for r in parts for seed in r]
    if not seeds or len(set(seeds)) != len(seeds):
        raise InputError(f"{what} needs distinct seeds, got {text!r}")
    return seeds


class TooManySeeds(InputError):
    """More seeds than a caller holds (``count`` of them), so it can say what to do instead."""

    def __init__(self, message: str, count: int) -> None:
        super().__init__(message)
        self.count = count


def seed_range(
    count: Any, start: Any, names: tuple[str, str] = ("--count", "--seed-start")
) -> list[int]:
    """The earlier spelling: ``count`` seeds from ``start``; ``names``: theirs in messages."""
    if not _is_int(count) or count < 1 or not _is_int(start) or start < 0:
        raise InputError(f"{names[0]} must be an integer >= 1 and {names[1]} >= 0")
    if count > MAX_SEEDS or start + count - 1 > MAX_SEED:
        raise InputError(
            f"{names[0]} {count} from {names[1]} {start}: at most {MAX_SEEDS} seeds, each in "
            f"0..{MAX_SEED}"
        )
    return list(range(start, start + count))


def seeds_text(seeds: list[int]) -> str:
    """``seeds`` in the grammar (runs of consecutive seeds as ranges): for messages."""
    runs: list[list[int]] = []
    for seed in seeds:
        if runs and seed == runs[-1][-1] + 1:
            runs[-1].append(seed)
        else:
            runs.append([seed])
    return ",".join(f"{r[0]}-{r[-1]}" if len(r) > 1 else str(r[0]) for r in runs)


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)  # TOML's true is no count
