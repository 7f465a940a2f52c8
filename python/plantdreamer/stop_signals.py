"""The signals that ask a long command to stop cleanly: Ctrl-C (SIGINT) and SIGTERM.

SIGTERM is what ``kill`` and cluster schedulers send before they kill a job. SIGINT gets a
handler of its own too: a shell starts background jobs with SIGINT ignored, and Python keeps
an inherited "ignore", so "Ctrl-C stops" would otherwise be false there.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from types import FrameType

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

Handler = Callable[[int, FrameType | None], object]


@contextlib.contextmanager
def stop_signals_handled(handler: Handler) -> Iterator[None]:
    """Calls ``handler`` on each STOP_SIGNALS inside the block; puts the old handlers back.

    Outside the main thread (where Python allows no handlers) it changes nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, handler) for sig in STOP_SIGNALS}
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
