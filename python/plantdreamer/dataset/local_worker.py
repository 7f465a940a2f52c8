"""A worker process of the local pool (``local_pool.py``):
``python -m plantdreamer.dataset.local_worker FD PARENT_PID``.

It talks to the driver over the socket ``FD`` (``multiprocessing.connection`` messages):
it receives ``("run", unit)`` and answers ``("started", plant_id, info)`` for each plant,
then ``("done", records)``; ``("stop", None)`` during a unit asks it to checkpoint and stop
(``worker.StopCheck`` polls for it); ``None`` or the socket's end makes it exit. It keeps
its models loaded between units (``worker.PlantWorker``).

It runs in a session of its own, so a terminal's Ctrl-C reaches the driver alone, which
asks the workers to stop as Ray's driver does; and it gets SIGTERM when the driver dies
(however it dies), which the trainer takes as a stop: checkpoint, then exit.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
from multiprocessing.connection import Connection
from typing import Any

PR_SET_PDEATHSIG = 1  # prctl(2): the signal this process gets when its parent dies
RUN, STARTED, DONE, STOP = "run", "started", "done", "stop"


class PipeBoard:
    """``tasks.Board`` over the driver's socket."""

    def __init__(self, conn: Connection) -> None:
        self.conn = conn
        self.stop_requested = False
        self.exit_requested = False

    def started(self, plant_id: str, info: dict[str, Any]) -> None:
        self.conn.send((STARTED, plant_id, info))

    def stopping(self) -> bool:
        while not self.stop_requested and self.conn.poll():
            try:
                message = self.conn.recv()
            except EOFError:  # the driver is gone: stop as it would have asked
                message = None
            if message is None:
                self.exit_requested = True
            if message is None or message[0] == STOP:
                self.stop_requested = True
        return self.stop_requested


def die_with_parent(parent: int) -> None:
    """SIGTERM to this process when the driver dies (Linux), and an exit now if it
    already has."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    except (OSError, AttributeError):  # no prctl: the socket's end still ends the worker
        pass
    if os.getppid() != parent:
        raise SystemExit(0)


def serve(conn: Connection) -> None:
    """Runs units until told to exit or the driver is gone."""
    from plantdreamer.dataset.worker import PlantWorker

    worker = PlantWorker()
    board = PipeBoard(conn)
    while not board.exit_requested:
        try:
            message = conn.recv()
        except EOFError:
            return
        if message is None:
            return
        if message[0] != RUN:  # a stop asked for between units: nothing runs
            continue
        board.stop_requested = False
        records = worker.run(message[1], board)
        conn.send((DONE, records))


def main(argv: list[str]) -> int:
    fd, parent = int(argv[1]), int(argv[2])
    die_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the driver's to take (own session)
    conn = Connection(fd)
    try:
        serve(conn)
    except (KeyboardInterrupt, BrokenPipeError, ConnectionResetError):
        return 0  # a stop while idle, or the driver went away mid-answer
    finally:
        conn.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
