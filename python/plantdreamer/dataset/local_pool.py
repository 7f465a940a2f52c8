"""A dataset's workers on this machine without Ray: worker processes (``local_worker.py``)
started by the driver, as many as the machine's CPUs and GPUs hold (``demand.py``).

Each worker is ``python -m plantdreamer.dataset.local_worker`` with a socket to the driver,
in a session of its own, its thread counts and GPUs in its environment (the GPUs it is
given in ``CUDA_VISIBLE_DEVICES``, an empty one without: as Ray does), its stderr in a
temporary file the driver reads only to say why a worker died. A worker is started when
the CPUs and GPUs it asks for are free, in the order asked, and holds them until it is
released. A worker that dies (killed, out of memory) is started again and its unit run
again, up to ``max_retries`` times, resuming from the checkpoints (Ray's rule); after that
its unit fails with one line saying how it died. Nothing listens on any port.
"""

from __future__ import annotations

import math
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from typing import IO, Any

from plantdreamer.dataset.demand import LOCAL_MORE, Demand, check_fits, fits
from plantdreamer.dataset.local_worker import DONE, RUN, STARTED, STOP
from plantdreamer.dataset.tasks import StatusBoard

WORKER_MODULE = "plantdreamer.dataset.local_worker"
EXIT_WAIT_S = 10.0  # how long a released or closing worker gets to exit before a kill
GPU_EPSILON = 1e-9


@dataclass(eq=False)
class LocalWorker:
    """A worker slot of the pool: its demand, its process (None until its resources are
    free) and the unit it runs."""

    demand: Demand
    max_retries: int
    env: dict[str, str]
    proc: subprocess.Popen | None = None
    conn: Connection | None = None
    stderr: IO[bytes] | None = None
    gpus: list[str] = field(default_factory=list)
    call: Call | None = None
    holds: bool = False  # its CPUs and GPUs are taken


@dataclass(eq=False)
class Call:
    """A unit handed to a worker: its request, retries so far and, once known, its result
    (the records, or one line saying why its worker was lost)."""

    worker: LocalWorker
    request: dict[str, Any]
    retries: int = 0
    result: dict[str, dict[str, Any]] | str | None = None


class LocalPool:
    """The ``workers.Workers`` of this machine: ``cpus`` CPUs and the GPUs ``gpu_ids``
    (``CUDA_VISIBLE_DEVICES`` entries)."""

    def __init__(self, cpus: int, gpu_ids: list[str]) -> None:
        self.resources = {"CPU": float(cpus), "GPU": float(len(gpu_ids))}
        self.free_cpus = float(cpus)
        self.free_gpus = {g: 1.0 for g in gpu_ids}
        self.workers: list[LocalWorker] = []
        self.waiting: list[LocalWorker] = []  # started, waiting for free resources
        self.board = StatusBoard()  # the starts' attempt numbers, kept in the driver
        self.stopping = False
        self.nodes: int | None = 1

    # -- workers.Workers ---------------------------------------------------------------

    def check_feasible(self, demands: set[Demand]) -> None:
        check_fits(demands, [self.resources], "this machine", LOCAL_MORE)

    def capacity(self, demand: Demand) -> int:
        return fits(demand, self.resources)

    def start(self, demand: Demand, max_retries: int, env: dict[str, str]) -> LocalWorker:
        worker = LocalWorker(demand, max_retries, dict(env))
        self.workers.append(worker)
        self.waiting.append(worker)
        self._start_waiting()
        return worker

    def submit(self, worker: LocalWorker, request: dict[str, Any]) -> Call:
        worker.call = Call(worker, request)
        if worker.holds:
            if worker.proc is None or worker.proc.poll() is not None:
                self._spawn(worker)  # one that died after its last unit
            self._send_unit(worker)
        return worker.call

    def wait(self, calls: list[Call], timeout: float) -> list[Call]:
        deadline = time.monotonic() + timeout
        while True:
            self._start_waiting()
            finished = [c for c in calls if c.result is not None]
            left = deadline - time.monotonic()
            if finished or left <= 0:
                return finished
            conns = {w.conn: w for w in self.workers if w.conn is not None}
            if not conns:
                time.sleep(min(left, 0.05))
                continue
            for conn in wait(list(conns), timeout=left):
                self._read(conns[conn])  # type: ignore[index]

    def result(self, call: Call) -> dict[str, dict[str, Any]] | str:
        assert call.result is not None
        return call.result

    def release(self, worker: LocalWorker) -> None:
        self._end(worker, ask=True)
        if worker in self.waiting:
            self.waiting.remove(worker)
        self.workers.remove(worker)

    def starts(self) -> list[dict[str, Any]]:
        return self.board.drain()

    def stop(self) -> None:
        self.stopping = True
        self.waiting.clear()  # a worker not started by now starts no unit
        for worker in self.workers:
            if worker.conn is not None and worker.call is not None:
                try:
                    worker.conn.send((STOP, None))
                except OSError:
                    pass  # it died: its end is read as such

    def close(self) -> None:
        """Every worker asked to exit (a unit still running: SIGTERM, which checkpoints),
        then killed if it has not within ``EXIT_WAIT_S``."""
        for worker in list(self.workers):
            self._end(worker, ask=worker.call is None or worker.call.result is not None)
        self.workers.clear()

    # -- processes ---------------------------------------------------------------------

    def _start_waiting(self) -> None:
        while self.waiting and self._take(self.waiting[0]):
            worker = self.waiting.pop(0)
            self._spawn(worker)
            if worker.call is not None:
                self._send_unit(worker)

    def _take(self, worker: LocalWorker) -> bool:
        """Takes the worker's CPUs and GPUs if they are free."""
        demand = worker.demand
        if demand.cpus > self.free_cpus + GPU_EPSILON:
            return False
        gpus = self._gpus_for(demand.gpus)
        if gpus is None:
            return False
        self.free_cpus -= demand.cpus
        share = demand.gpus if demand.gpus <= 1 else 1.0
        for g in gpus:
            self.free_gpus[g] -= share
        worker.gpus, worker.holds = gpus, True
        return True

    def _gpus_for(self, amount: float) -> list[str] | None:
        if amount <= 0:
            return []
        if amount <= 1:  # a share of one GPU
            return next(([g] for g, free in self.free_gpus.items()
                         if free >= amount - GPU_EPSILON), None)  # fmt: skip
        whole = [g for g, free in self.free_gpus.items() if free >= 1 - GPU_EPSILON]
        needed = math.ceil(amount - GPU_EPSILON)
        return whole[:needed] if len(whole) >= needed else None

    def _give_back(self, worker: LocalWorker) -> None:
        if worker.holds:
            self.free_cpus += worker.demand.cpus
            share = worker.demand.gpus if worker.demand.gpus <= 1 else 1.0
            for g in worker.gpus:
                self.free_gpus[g] += share
            worker.holds, worker.gpus = False, []

    def _spawn(self, worker: LocalWorker) -> None:
        ours, theirs = socket.socketpair()
        env = {**os.environ, **worker.demand.thread_env(), **worker.env}
        env["CUDA_VISIBLE_DEVICES"] = ",".join(worker.gpus)
        worker.stderr = tempfile.TemporaryFile()
        try:
            worker.proc = subprocess.Popen(
                [sys.executable, "-m", WORKER_MODULE, str(theirs.fileno()), str(os.getpid())],
                pass_fds=[theirs.fileno()], env=env, stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL, stderr=worker.stderr, start_new_session=True,
            )  # fmt: skip
        finally:
            theirs.close()
        worker.conn = Connection(ours.detach())

    def _send_unit(self, worker: LocalWorker) -> None:
        assert worker.conn is not None and worker.call is not None
        try:
            worker.conn.send((RUN, worker.call.request))
        except OSError:
            pass  # it died already: wait() reads its end and retries the unit

    def _read(self, worker: LocalWorker) -> None:
        """Every message the worker has sent; its end, if it died."""
        assert worker.conn is not None
        try:
            while worker.conn.poll():
                message = worker.conn.recv()
                if message[0] == STARTED:
                    self.board.started(message[1], message[2])
                elif message[0] == DONE and worker.call is not None:
                    worker.call.result = message[1]
        except (EOFError, OSError):
            self._died(worker)

    def _died(self, worker: LocalWorker) -> None:
        """Its process ended: its unit runs again in a new one, or fails once its retries
        are spent (or the run is stopping)."""
        how = self._reap(worker)
        call = worker.call
        if call is None or call.result is not None:
            return
        if call.retries < worker.max_retries and not self.stopping:
            call.retries += 1
            self._spawn(worker)
            self._send_unit(worker)
            return
        tries = f", after {call.retries} retries" if call.retries else ""
        call.result = f"WorkerDied: the worker process {how}{tries}"

    def _reap(self, worker: LocalWorker) -> str:
        """How the worker's process ended (its stderr's last line, when it left one)."""
        proc, code = worker.proc, None
        if proc is not None:
            try:
                code = proc.wait(timeout=EXIT_WAIT_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                code = proc.wait()
        if worker.conn is not None:
            worker.conn.close()
        worker.proc = worker.conn = None
        how = f"(pid {proc.pid if proc else '?'}) " + _ending(code)
        # An error exit's cause is its last line (a killed process may have printed
        # anything before): an import that failed, a missing library.
        last = _last_line(worker.stderr) if code is not None and code > 0 else ""
        if worker.stderr is not None:
            worker.stderr.close()
            worker.stderr = None
        return how + (f": {last}" if last else "")

    def _end(self, worker: LocalWorker, ask: bool) -> None:
        proc = worker.proc
        if proc is not None and proc.poll() is None:
            try:
                if ask and worker.conn is not None:
                    worker.conn.send(None)
                else:
                    proc.send_signal(signal.SIGTERM)
            except OSError:
                pass
        if proc is not None:
            self._reap(worker)
        self._give_back(worker)


def _ending(code: int | None) -> str:
    if code is None:
        return "ended"
    if code < 0:
        try:
            return f"was killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"was killed by signal {-code}"
    return f"exited with status {code}"


def _last_line(stderr: IO[bytes] | None) -> str:
    if stderr is None:
        return ""
    try:
        stderr.seek(0)
        lines = stderr.read().decode(errors="replace").strip().splitlines()
    except OSError:
        return ""
    return lines[-1].strip()[:300] if lines else ""
