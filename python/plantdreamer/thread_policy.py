"""OpenMP's wait policy, settled before torch loads its OpenMP runtime.

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
"""

from __future__ import annotations

import os
import sys

VARIABLE = "OMP_WAIT_POLICY"
POLICY = "PASSIVE"


def settle() -> bool:
    """Sets ``OMP_WAIT_POLICY=PASSIVE`` unless the user chose a policy. False when torch is
    already loaded (its OpenMP runtime has read the environment; nothing is changed)."""
    if "torch" in sys.modules:
        return False
    os.environ.setdefault(VARIABLE, POLICY)
    return True
