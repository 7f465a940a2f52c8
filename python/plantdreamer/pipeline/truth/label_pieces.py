"""Specks out of a view's label map: small stray pieces of an object take the label around them.

A view's labels come from a per-pixel arg-max, so where two leaves cross with nearly equal
weight, or a leaf's edge grazes the 0.5 alpha threshold, a few pixels of one object land
apart from the rest of it: 1-4 px pieces that nobody would outline as part of a leaf, and
that a YOLO polygon or a connected-piece count takes for objects of their own. The rule
(docs/labels.md): in every view, an object (a key of the map: a leaf instance, or a class
without instances such as stem, pot or soil) keeps its largest 8-connected piece and every
piece of at least ``MIN_PIECE`` pixels; a smaller piece takes the key most frequent on its
border (8-neighbours outside it; background too, so a stray island is removed). Only pieces
are changed, never whole objects: a leaf seen as 3 pixels in all stays a 3-pixel leaf.

Pieces are found without a full labelling: ``MIN_PIECE - 1`` rounds of min-index
propagation between equal 8-neighbours converge on every piece of fewer than ``MIN_PIECE``
pixels (its geodesic diameter is smaller), and a converged candidate is a whole piece
exactly when no equal neighbour outside it carries another index.
"""

from __future__ import annotations

import numpy as np

MIN_PIECE = 16  # pixels: a piece of an object under this (not its largest) is a speck
BACKGROUND = -1  # the key of background pixels (not an object: never grown into)
PASSES = 4  # rounds of reassignment (a speck bordered only by specks waits for the next)

# The 8 neighbours as (dy, dx).
_STEPS = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)]


def remove_specks(key: np.ndarray, min_piece: int = MIN_PIECE) -> np.ndarray:
    """``key`` [H, W] (int64: ``BACKGROUND`` where no object, else an object's key >= 0)
    with every speck reassigned."""
    out = np.array(key, dtype=np.int64)
    ys, xs = np.nonzero(out != BACKGROUND)
    if min_piece <= 1 or not len(ys):
        return out
    # The objects' bounding box and one pixel around (background, or off the image: the
    # same to the rule), edited in a contiguous copy.
    y0, y1 = max(int(ys.min()) - 1, 0), min(int(ys.max()) + 2, out.shape[0])
    x0, x1 = max(int(xs.min()) - 1, 0), min(int(xs.max()) + 2, out.shape[1])
    crop = np.ascontiguousarray(out[y0:y1, x0:x1])
    for _ in range(PASSES):
        if not _reassign(crop, min_piece):
            break
    out[y0:y1, x0:x1] = crop
    return out


def _reassign(key: np.ndarray, min_piece: int) -> bool:
    """One round over ``key`` (edited in place); False when it holds no speck."""
    h, w = key.shape
    flat_key = key.reshape(-1)
    # Pixels of a uniform side x side block are in a piece of at least min_piece pixels:
    # they are left out of the search, as one node ("large") their neighbours can reach.
    large = _in_uniform_block(key, int(np.ceil(np.sqrt(min_piece)))).reshape(-1)
    pixels = np.flatnonzero((flat_key != BACKGROUND) & ~large)
    if not len(pixels):
        return False
    neighbours = _neighbours(key, pixels, large)
    piece, small = _small_pieces(neighbours, len(pixels), min_piece)
    if not len(small):
        return False
    # A key whose pixels are not all in small pieces has a larger piece, so all its small
    # pieces are specks; otherwise its largest small piece (ties: the first) is kept.
    sizes = np.bincount(piece, minlength=len(pixels) + 1)[small]
    keys, key_index = np.unique(flat_key[pixels[small - 1]], return_inverse=True)
    key_index = key_index.reshape(-1)
    totals = np.bincount(flat_key[flat_key != BACKGROUND])[keys]
    in_small = np.bincount(key_index, weights=sizes, minlength=len(keys))
    order = np.lexsort((np.arange(len(small)), -sizes, key_index))  # per key: largest first
    first = np.ones(len(small), dtype=bool)
    first[order[1:]] = key_index[order[1:]] != key_index[order[:-1]]
    keep = first & (in_small[key_index] == totals[key_index])
    n = len(pixels) + 1  # node 0 is "large"; pixel i is node i + 1; n: background
    is_speck = np.zeros(n + 1, dtype=bool)
    is_speck[small[~keep]] = True
    speck_nodes = np.flatnonzero(is_speck[np.r_[0, piece[1:]]])
    if not len(speck_nodes):
        return False
    # Border votes: each (speck pixel, neighbour outside its piece) pair votes for the
    # neighbour's key (background included; pixels of other specks do not vote: they move
    # too). Neighbours off the image do not vote.
    node = np.zeros(h * w, dtype=np.int64)  # 0: a pixel of a large piece
    node[flat_key == BACKGROUND] = n
    node[pixels] = np.arange(1, n)
    piece_of = np.r_[piece, n]  # the background is its own "piece", never a speck
    py, px = np.divmod(pixels[speck_nodes - 1], w)
    votes_piece, votes_key = [], []
    for dy, dx in _STEPS:
        ny, nx = py + dy, px + dx
        inside = (ny >= 0) & (ny < h) & (nx >= 0) & (nx < w)
        at = ny[inside] * w + nx[inside]
        own, other = piece[speck_nodes[inside]], piece_of[node[at]]
        votes = (other != own) & ~is_speck[other]
        votes_piece.append(own[votes])
        votes_key.append(flat_key[at][votes])
    vp, vk = np.concatenate(votes_piece), np.concatenate(votes_key)
    if not len(vp):
        return False
    # The most frequent key per speck (ties: the smaller key, so background first).
    pairs, counts = np.unique(np.stack([vp, vk], axis=1), axis=0, return_counts=True)
    pairs = pairs[np.lexsort((pairs[:, 1], -counts, pairs[:, 0]))]
    winner = np.ones(len(pairs), dtype=bool)
    winner[1:] = pairs[1:, 0] != pairs[:-1, 0]
    new_key = np.full(n, BACKGROUND - 1, dtype=np.int64)
    new_key[pairs[winner, 0]] = pairs[winner, 1]
    moving = speck_nodes[new_key[piece[speck_nodes]] != BACKGROUND - 1]
    flat_key[pixels[moving - 1]] = new_key[piece[moving]]
    return len(moving) > 0


def _in_uniform_block(key: np.ndarray, side: int) -> np.ndarray:
    """[H, W] bool: the pixel lies in some side x side block of one key."""
    h, w = key.shape
    if h < side or w < side:
        return np.zeros((h, w), dtype=bool)
    # Blocks by top-left corner: every horizontal and vertical neighbour pair inside equal.
    right = np.zeros((h, w), dtype=bool)
    right[:, :-1] = key[:, 1:] == key[:, :-1]
    down = np.zeros((h, w), dtype=bool)
    down[:-1] = key[1:] == key[:-1]
    corner = _run(_run(right, side - 1, axis=1), side, axis=0) & _run(
        _run(down, side - 1, axis=0), side, axis=1
    )
    # Each pixel of a uniform block: the block corners at most side - 1 above and left.
    return _spread(_spread(corner, side, axis=0), side, axis=1)


def _run(mask: np.ndarray, length: int, axis: int) -> np.ndarray:
    """mask[i] & mask[i + 1] & ... & mask[i + length - 1] along ``axis`` (False past the
    end)."""
    m = np.moveaxis(mask, axis, 0)
    out = m.copy()
    for k in range(1, length):
        out[:-k] &= m[k:]
        out[-k:] = False
    return np.moveaxis(out, 0, axis)


def _spread(mask: np.ndarray, length: int, axis: int) -> np.ndarray:
    """mask[i] | mask[i - 1] | ... | mask[i - length + 1] along ``axis``."""
    m = np.moveaxis(mask, axis, 0)
    out = m.copy()
    for k in range(1, length):
        out[k:] |= m[:-k]
    return np.moveaxis(out, 0, axis)


def _neighbours(key: np.ndarray, pixels: np.ndarray, large: np.ndarray) -> list[np.ndarray]:
    """Per direction, the node of each of ``pixels``' neighbour of the same key: 0 for a
    pixel of a large piece, i + 1 for pixels[i], ``len(pixels) + 1`` where the neighbour is
    off the image or of another key."""
    h, w = key.shape
    none = len(pixels) + 1
    node = np.full((h + 2) * (w + 2), none, dtype=np.int32)
    node.reshape(h + 2, w + 2)[1:-1, 1:-1][large.reshape(h, w)] = 0
    py, px = np.divmod(pixels, w)
    padded = (py + 1) * (w + 2) + (px + 1)
    node[padded] = np.arange(1, none, dtype=np.int32)
    padded_key = np.pad(key, 1, constant_values=BACKGROUND).reshape(-1)
    own = padded_key[padded]
    out = []
    for dy, dx in _STEPS:
        at = padded + dy * (w + 2) + dx
        out.append(np.where(padded_key[at] == own, node[at], np.int32(none)))
    return out


def _small_pieces(
    neighbours: list[np.ndarray], count: int, min_piece: int
) -> tuple[np.ndarray, np.ndarray]:
    """Each node's piece after at most ``min_piece - 1`` rounds (the smallest node reached;
    0 for pieces that reach a large one; [count + 1]), and the nodes naming whole pieces of
    fewer than ``min_piece`` pixels."""
    n = count + 1
    piece = np.arange(n + 1, dtype=np.int32)
    piece[n] = np.iinfo(np.int32).max  # "no neighbour": never the smaller
    head = piece[1:n]
    for _ in range(min_piece - 1):
        before = head.copy()
        for nb in neighbours:
            np.minimum(head, piece[nb], out=head)
        # Pointer jumping: a node names a pixel of the same piece, which may have reached
        # a smaller one already (only speeds convergence; a piece never takes another's).
        head[:] = piece[head]
        if np.array_equal(head, before):
            break
    # Not converged: some neighbour of the same key carries another node.
    open_ = np.zeros(count, dtype=bool)
    for nb in neighbours:
        open_ |= (nb < n) & (piece[nb] != head)
    sizes = np.bincount(head, minlength=n)
    bad = np.zeros(n, dtype=bool)
    bad[head[open_]] = True
    bad[0] = True
    small = np.flatnonzero((sizes > 0) & (sizes < min_piece) & ~bad)
    return piece[:n].astype(np.int64), small
