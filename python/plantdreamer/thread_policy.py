"""torch's OpenMP threads: their wait policy, settled before torch loads its runtime, and
their count, pinned for a run.

torch runs its CPU ops on an OpenMP pool (libgomp in the pip wheels); the rasterizer runs
on rayon's pool. Under libgomp's default policy every OpenMP worker keeps spinning for
300,000 iterations (milliseconds) after each parallel torch op, so the torch ops around a
rasterizer call (loss, background, Adam) leave spinning threads on the very cores rayon's
workers need next. With PASSIVE they sleep as soon as their work is done. Measured on the
2-core benchmark machine under load: BENCHMARKS.md, "Whole call and threads".

libgomp reads the variable once, when it is loaded, which is the first ``import torch``.
So ``plantdreamer/__init__.py`` (which imports no torch) calls ``settle()``: importing
plantdreamer before torch is enough, and the CLI always does. A value the user set
(``OMP_WAIT_POLICY=ACTIVE``, or ``GOMP_SPINCOUNT``) is kept. When torch was loaded first,
the setting would come too late and is not made (``settle`` returns False).

The count: torch splits a reduction (a sum, a matrix product, a convolution) into one chunk
per thread, so its bits follow the thread count, which torch takes from the cores the
process may use. ``pinned_torch_threads`` fixes it for a block (a run's ``torch-threads``),
so the same run gives the same bits on one core or sixty-four. torch's inter-op pool is
left alone: eager ops and the CPU autograd run on the calling thread, never on it.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager

VARIABLE = "OMP_WAIT_POLICY"
POLICY = "PASSIVE"


def settle() -> bool:
    """Sets ``OMP_WAIT_POLICY=PASSIVE`` unless the user chose a policy. False when torch is
    already loaded (its OpenMP runtime has read the environment; nothing is changed)."""
    if "torch" in sys.modules:
        return False
    os.environ.setdefault(VARIABLE, POLICY)
    return True


@contextmanager
def pinned_torch_threads(threads: int) -> Iterator[None]:
    """torch's intra-op thread count is ``threads`` within the block, then as it was.

    Threads started inside the block (a run's pools) take the count on their first torch
    op; a thread that ran one before the block keeps its own (OpenMP's count is per
    thread), so the block is entered before a run starts any."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)
