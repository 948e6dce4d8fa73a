"""Writing a flush whole: a Ctrl-C (or a ``SIGTERM`` handler) waits for its end (:func:`held`).

A flush moves a stream's rows out of its block, counts them into their episodes and writes them:
an exception raised by a signal handler halfway would drop rows already counted (the file's
episodes would then say more steps than it holds). Python runs signal handlers in the main
thread only, between bytecodes; :func:`held` puts handlers there that note the signal, and calls
the user's own handlers once the flush is done.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

__all__ = ["held"]

_HELD = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM") if hasattr(signal, name))


@contextmanager
def held() -> Iterator[None]:
    """Run the block with ``SIGINT`` and ``SIGTERM``'s Python handlers called after it.

    Only signals with a Python handler (``default_int_handler``, which raises
    ``KeyboardInterrupt``, or the user's own) are held; a default or ignored one acts as it
    does. The same signal a second time is not held (a flush stuck on a hung disk can still be
    interrupted). Outside the main thread, where no handler runs, the block runs as it is.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    came: list[tuple[int, FrameType | None]] = []

    def note(signum: int, frame: FrameType | None) -> None:
        if any(signum == earlier for earlier, _ in came):  # the second: not held any more
            came.clear()
            saved[signum](signum, frame)
        else:
            came.append((signum, frame))

    saved: dict[int, Any] = {}
    try:
        for signum in _HELD:
            handler = signal.getsignal(signum)
            if callable(handler):
                saved[signum] = handler
                signal.signal(signum, note)
        yield
    finally:
        for signum, handler in saved.items():
            signal.signal(signum, handler)
        for signum, frame in came:
            saved[signum](signum, frame)
