"""Specks out of label maps (plantdreamer.pipeline.truth.label_pieces) against a slow reference."""

from __future__ import annotations

import numpy as np
import pytest

from label_pieces_reference import reference, specks
from plantdreamer.pipeline.truth.label_pieces import BACKGROUND, MIN_PIECE, remove_specks


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
