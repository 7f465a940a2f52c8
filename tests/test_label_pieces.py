"""Specks out of label maps (plantdreamer.pipeline.label_pieces) against a slow reference."""

from __future__ import annotations

from collections import Counter, deque

import numpy as np
import pytest

from plantdreamer.pipeline.label_pieces import BACKGROUND, MIN_PIECE, PASSES, remove_specks

STEPS = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)]


def pieces(key: np.ndarray) -> list[list[tuple[int, int]]]:
    """Every 8-connected piece of equal keys (background included), by breadth-first search,
    in raster order of their first pixel."""
    h, w = key.shape
    seen = np.zeros((h, w), dtype=bool)
    out = []
    for y in range(h):
        for x in range(w):
            if seen[y, x]:
                continue
            seen[y, x] = True
            piece, queue = [], deque([(y, x)])
            while queue:
                cy, cx = queue.popleft()
                piece.append((cy, cx))
                for dy, dx in STEPS:
                    ny, nx = cy + dy, cx + dx
                    if 0 <= ny < h and 0 <= nx < w and not seen[ny, nx]:
                        if key[ny, nx] == key[y, x]:
                            seen[ny, nx] = True
                            queue.append((ny, nx))
            out.append(piece)
    return out


def specks(key: np.ndarray, min_piece: int) -> list[list[tuple[int, int]]]:
    """The pieces the rule moves: an object's pieces under min_piece pixels except its
    largest (ties: the first in raster order)."""
    by_key: dict[int, list[list[tuple[int, int]]]] = {}
    for piece in pieces(key):
        by_key.setdefault(int(key[piece[0]]), []).append(piece)
    out = []
    for k, ps in by_key.items():
        if k == BACKGROUND:
            continue
        largest = max(range(len(ps)), key=lambda i: (len(ps[i]), -i))
        out += [p for i, p in enumerate(ps) if i != largest and len(p) < min_piece]
    return out


def reference(key: np.ndarray, min_piece: int = MIN_PIECE) -> np.ndarray:
    """The rule, slowly: each pass moves every speck to the key most frequent over its
    (pixel, outside neighbour) pairs, neighbours in other specks not voting; ties to the
    smaller key."""
    key = key.copy()
    h, w = key.shape
    for _ in range(PASSES):
        found = specks(key, min_piece)
        moving = {px for p in found for px in p}
        new = key.copy()
        changed = False
        for piece in found:
            inside = set(piece)
            votes: Counter[int] = Counter()
            for y, x in piece:
                for dy, dx in STEPS:
                    ny, nx = y + dy, x + dx
                    if 0 <= ny < h and 0 <= nx < w and (ny, nx) not in inside:
                        if (ny, nx) not in moving:
                            votes[int(key[ny, nx])] += 1
            if votes:
                best = min(votes, key=lambda k: (-votes[k], k))
                for px in piece:
                    new[px] = best
                changed = True
        key = new
        if not changed:
            break
    return key


def random_key(rng: np.random.Generator, h: int, w: int, noise: float) -> np.ndarray:
    """Blocks of a few keys (some background) sprinkled with single-pixel noise."""
    block = int(rng.integers(3, 9))
    base = rng.integers(-1, 4, (h // block + 1, w // block + 1))
    key = np.kron(base, np.ones((block, block), dtype=np.int64))[:h, :w]
    sprinkle = rng.random((h, w)) < noise
    return np.where(sprinkle, rng.integers(-1, 7, (h, w)), key)


@pytest.mark.parametrize("seed", range(40))
def test_specks_match_the_slow_reference(seed):
    rng = np.random.default_rng(seed)
    h, w = (int(v) for v in rng.integers(1, 48, 2))
    key = random_key(rng, h, w, float(rng.uniform(0.0, 0.25)))
    min_piece = int(rng.choice([2, 5, MIN_PIECE]))
    np.testing.assert_array_equal(remove_specks(key, min_piece), reference(key, min_piece))


def test_no_object_keeps_a_speck_and_whole_small_objects_stay():
    rng = np.random.default_rng(7)
    key = random_key(rng, 96, 120, 0.05)
    out = remove_specks(key)
    assert not specks(out, MIN_PIECE)
    # Background never becomes an object; objects seen only as specks keep one piece.
    assert (out[key == BACKGROUND] == BACKGROUND).all()
    assert set(np.unique(out)) == set(np.unique(key))


def test_a_speck_takes_the_object_around_it():
    key = np.full((20, 20), BACKGROUND, dtype=np.int64)
    key[2:18, 2:18] = 1  # a leaf
    key[8:10, 8:10] = 2  # 4 px of another leaf, whose main piece is elsewhere
    key[0:5, 0:1] = 2
    key[0, 0:16] = 2
    key[19, 19] = 1  # a stray pixel of the first leaf in the background
    out = remove_specks(key)
    assert (out[8:10, 8:10] == 1).all() and out[19, 19] == BACKGROUND
    # The 16-px row and its column stay (a piece of MIN_PIECE pixels is an object's own).
    assert (out[0, 0:16] == 2).all() and (out[0:5, 0] == 2).all()
    # Nothing to do: the same map back.
    np.testing.assert_array_equal(remove_specks(out), out)
    assert (remove_specks(key, 1) == key).all()
