"""Depth conditioning one step ahead, as a task of the trainer's host pool.

The ControlNet's depth map depends only on the fixed initial Gaussians and the camera, and
the camera sequence is fixed by the seed, so the next step's map can be computed while the
current step runs the networks. The rasterizer releases the GIL and torch's kernels do too,
so the task really runs beside the step's thread. The maps are the same bits either way:
the same deterministic calls, only earlier (tests/test_gpu_path.py compares plant.ply).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Executor, Future

import torch

from plantdreamer.cameras import Camera
from plantdreamer.guidance.depth import DepthConditioner


class DepthAhead:
    """``get(camera)`` returns the conditioning of ``camera`` and, given a ``pool``, starts
    the one of ``next_camera()`` as a task of it (None: each is made in line). One task at
    a time: the conditioner (and its cache) is never used by two threads at once."""

    def __init__(
        self,
        conditioner: DepthConditioner,
        next_camera: Callable[[], Camera],
        pool: Executor | None = None,
    ) -> None:
        self.conditioner = conditioner
        self.next_camera = next_camera
        self._pool = pool
        self._pending: tuple[tuple, Future[torch.Tensor]] | None = None

    def get(self, camera: Camera, more: bool = True) -> torch.Tensor:
        """[1, 1, s, s] conditioning of ``camera``; ``more``: another step follows."""
        key = DepthConditioner.key(camera)
        pending, self._pending = self._pending, None
        cond = None
        if pending is not None:
            result = pending[1].result()  # also when unused: no task may be running
            if pending[0] == key:
                cond = result
        if cond is None:
            cond = self.conditioner([camera])
        if self._pool is not None and more:
            nxt = self.next_camera()
            self._pending = (DepthConditioner.key(nxt), self._pool.submit(self._compute, [nxt]))
        return cond

    def _compute(self, cameras: Sequence[Camera]) -> torch.Tensor:
        with torch.no_grad():
            return self.conditioner(cameras)

    def close(self) -> None:
        """Waits for a task still running (the pool is the trainer's, and outlives this)."""
        if self._pending is not None and not self._pending[1].cancel():
            self._pending[1].exception()
        self._pending = None
