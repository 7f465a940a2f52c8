"""A slow reference for the label maps' pieces: breadth-first 8-connected pieces, the specks
that ``plantdreamer.pipeline.truth.label_pieces`` moves, and its rule applied pass by pass."""

from __future__ import annotations

from collections import Counter, deque

import numpy as np

from plantdreamer.pipeline.truth.label_pieces import BACKGROUND, MIN_PIECE, PASSES

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
