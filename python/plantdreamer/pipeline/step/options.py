"""How a training step runs where either choice gives the same bits: the variants
``benches/bench_throughput.py`` compares, passed to the trainer (never module switches)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class StepOptions:
    """``depth_ahead``: the next step's depth conditioning is made on the trainer's host
    pool during this step (False: in line, when the guidance needs it).
    ``sleeping_wait``: the host thread sleeps while it waits for the device
    (``guidance/in_flight.py``); False spins, as CUDA's default wait does (kept until it
    is measured on a GPU: ``bench_throughput.py --cuda-wait spin sleep``)."""

    depth_ahead: bool = True
    sleeping_wait: bool = True
