"""A flush written whole: signals held meanwhile (record/signals.py)."""

from __future__ import annotations

import signal
import threading
from types import FrameType

import pytest

from episode_audit.record.signals import held


@pytest.mark.usefixtures("ctrl_c")
def flush(done: list[str], times: int = 1) -> None:
    """A flush in which Ctrl-C is pressed ``times`` times."""
    with held():
        for n in range(times):
            signal.raise_signal(signal.SIGINT)
            done.append(f"after {n + 1}")


def test_a_ctrl_c_is_raised_after_the_block() -> None:
    done: list[str] = []
    with pytest.raises(KeyboardInterrupt):
        flush(done)
    assert done == ["after 1"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


@pytest.mark.usefixtures("ctrl_c")
def test_a_second_ctrl_c_is_not_held() -> None:
    done: list[str] = []
    with pytest.raises(KeyboardInterrupt):
        flush(done, times=2)
    assert done == ["after 1"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_users_sigterm_handler_runs_after_the_block_with_its_signal() -> None:
    came: list[tuple[int, str]] = []
    order: list[str] = []

    def handler(signum: int, frame: FrameType | None) -> None:
        came.append((signum, "handled"))
        order.append("handler")

    before = signal.signal(signal.SIGTERM, handler)
    try:
        with held():
            signal.raise_signal(signal.SIGTERM)
            order.append("block")
        assert came == [(signal.SIGTERM, "handled")] and order == ["block", "handler"]
        assert signal.getsignal(signal.SIGTERM) is handler
    finally:
        signal.signal(signal.SIGTERM, before)


def test_outside_the_main_thread_nothing_is_changed() -> None:
    seen = []

    def flush_here() -> None:
        with held():
            seen.append(signal.getsignal(signal.SIGINT))

    before = signal.getsignal(signal.SIGINT)
    thread = threading.Thread(target=flush_here)
    thread.start()
    thread.join()
    assert seen == [before]
