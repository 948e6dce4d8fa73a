"""Work spread over local processes or Ray tasks, results back in input order.

:func:`map_ordered` runs ``fn(item, progress)`` for each item: in this process (``jobs=1``),
in a :class:`~concurrent.futures.ProcessPoolExecutor` of spawned workers (``jobs > 1``), or as
Ray tasks (``ray_address``). Workers read their inputs themselves (an item is a path, or a path
and a batch of episodes); only results travel back. Results come back in input order whatever
the order the work ends in, so the output of a command does not depend on ``jobs``.
:func:`usable_cores` is the default ``jobs`` of the command line. How to choose: docs/scale.md.
"""

from __future__ import annotations

import os
import signal
import socket
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, wait
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar
from urllib.parse import urlsplit

from .errors import ConfigurationError, EpisodeAuditError

__all__ = [
    "RAY_CONNECT_TIMEOUT",
    "Progress",
    "check_jobs",
    "map_ordered",
    "usable_cores",
    "workers",
]

T = TypeVar("T")
R = TypeVar("R")
R_co = TypeVar("R_co", covariant=True)
T_contra = TypeVar("T_contra", contravariant=True)
Progress = Callable[[int], None]
"""Told how many more steps are done (a progress bar's ``advance``)."""

RAY_CONNECT_TIMEOUT = 10.0
"""Seconds to wait for a Ray cluster's address to answer before giving up (exit 2)."""


class Work(Protocol[T_contra, R_co]):
    """A job's function: one item's work, telling ``progress`` (if given) of its steps."""

    def __call__(self, item: T_contra, progress: Progress | None, /) -> R_co: ...


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def check_jobs(jobs: int | None, *, option: str = "jobs") -> int:
    """``jobs`` checked (an int >= 1); ``None`` is :func:`usable_cores`."""
    if jobs is None:
        return usable_cores()
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ConfigurationError(f"{option}: expected a number of processes >= 1, got {jobs!r}")
    return jobs


def workers(jobs: int | None, ray_address: str | None = None) -> int:
    """How many items run at a time: ``jobs`` checked, or the CPUs of the Ray cluster."""
    if ray_address is None:
        return check_jobs(jobs)
    return max(1, int(_connect(ray_address).cluster_resources().get("CPU", 1)))


def map_ordered(
    fn: Work[T, R],
    items: Iterable[T],
    *,
    jobs: int | None = 1,
    ray_address: str | None = None,
    progress: Progress | None = None,
) -> Iterator[R]:
    """``fn(item, progress)`` for each of ``items``, yielded in the order of ``items``.

    ``jobs=1`` runs them here, one after another; ``jobs > 1`` (``None``: every usable core)
    in that many worker processes (at most one per item), each started afresh (``spawn``:
    nothing of this process, an env or a GL context, is inherited); ``ray_address`` as Ray
    tasks (``"local"``: a Ray started here, ``"auto"`` or ``"ray://HOST:PORT"``: a running
    cluster). ``fn`` and the items must then be picklable (a module-level function, or a
    :func:`functools.partial` of one). Progress from workers counts when an item is done.

    An :class:`~episode_audit.errors.EpisodeAuditError` ``fn`` raises is raised here, at its
    item's place in the order. On any exit before the end (an error, ``KeyboardInterrupt``, the
    iterator closed) the work not done is cancelled and the workers are stopped.

    >>> list(map_ordered(lambda item, progress: item * 2, [1, 2, 3]))
    [2, 4, 6]
    """
    work = list(items)
    if ray_address is not None:
        yield from _ray_map(fn, work, ray_address, progress)
        return
    workers = min(check_jobs(jobs), len(work))
    if workers <= 1:
        for item in work:
            yield fn(item, progress)
        return
    yield from _pool_map(fn, work, workers, progress)


@dataclass(frozen=True)
class _Done(Generic[R]):
    """What a worker sends back: the result or the expected error, and the steps it did."""

    result: R | None
    error: EpisodeAuditError | None
    steps: int

    def unwrap(self, progress: Progress | None) -> R:
        if progress is not None and self.steps:
            progress(self.steps)
        if self.error is not None:
            raise self.error
        return self.result  # type: ignore[return-value]


def _call(fn: Work[T, R], chunk: Sequence[T]) -> list[_Done[R]]:
    """Run a chunk of items in a worker, counting their progress instead of reporting it."""
    done: list[_Done[R]] = []
    for item in chunk:
        steps = 0

        def count(n: int) -> None:
            nonlocal steps
            steps += n

        try:
            done.append(_Done(fn(item, count), None, steps))
        except EpisodeAuditError as exc:
            done.append(_Done(None, exc, steps))
    return done


def _chunks(work: Sequence[T], workers: int) -> list[Sequence[T]]:
    """``work`` cut in runs of items, about 8 a worker: few round trips, workers kept busy."""
    size = max(1, len(work) // (8 * workers))
    return [work[i : i + size] for i in range(0, len(work), size)]


def _quiet_worker() -> None:
    """A worker leaves Ctrl-C to the parent (which stops it): no traceback per worker."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _pool_map(
    fn: Work[T, R], work: Sequence[T], workers: int, progress: Progress | None
) -> Iterator[R]:
    import multiprocessing

    context = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(workers, mp_context=context, initializer=_quiet_worker)
    futures: list[Future[list[_Done[R]]]] = []
    try:
        with _workers_ignore_sigint():
            futures = [pool.submit(_call, fn, chunk) for chunk in _chunks(work, workers)]
        for future in futures:
            for done in future.result():
                yield done.unwrap(progress)
    except BaseException:
        _stop(pool, futures)
        raise
    pool.shutdown(wait=True)


@contextmanager
def _workers_ignore_sigint() -> Iterator[None]:
    """Workers started in here ignore Ctrl-C from their first instruction on.

    An ignored signal stays ignored in a started program, and Python then sets no handler of
    its own: a worker still importing when Ctrl-C comes prints no traceback; the parent,
    which handles it, stops the workers.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _stop(pool: ProcessPoolExecutor, futures: Sequence[Future[Any]]) -> None:
    """Cancel what has not started and end the workers now (they may be mid-item)."""
    for future in futures:
        future.cancel()
    terminate = getattr(pool, "terminate_workers", None)  # Python >= 3.14
    if terminate is not None:
        terminate()
    else:
        for process in list((getattr(pool, "_processes", None) or {}).values()):
            process.terminate()
    pool.shutdown(wait=True, cancel_futures=True)
    wait(futures, timeout=0)


def _ray_map(
    fn: Work[T, R], work: Sequence[T], address: str, progress: Progress | None
) -> Iterator[R]:
    ray = _connect(address)
    remote = ray.remote(num_cpus=1, max_retries=0)(_call)
    refs: list[Any] = []
    try:
        refs = [remote.remote(fn, chunk) for chunk in _chunks(work, workers(None, address))]
        for ref in refs:
            chunk_done: list[_Done[R]] = ray.get(ref)
            for done in chunk_done:
                yield done.unwrap(progress)
    except BaseException:
        for ref in refs:
            ray.cancel(ref, force=True)
        raise


def _connect(address: str) -> Any:
    """Ray, connected to ``address`` (an unreachable cluster: ConfigurationError, no hang).

    Ray's own wait for a cluster's control store (about 20 s by default) is cut to
    :data:`RAY_CONNECT_TIMEOUT` and its retry log lines are left out, unless the environment
    says otherwise (``RAY_gcs_server_port_wait_time_s``, ``RAY_BACKEND_LOG_LEVEL``).
    """
    if address != "local":
        os.environ.setdefault("RAY_gcs_server_port_wait_time_s", f"{RAY_CONNECT_TIMEOUT:.0f}")
        os.environ.setdefault("RAY_BACKEND_LOG_LEVEL", "fatal")
    try:
        import ray
    except ImportError:
        raise ConfigurationError("--ray needs Ray: pip install 'episode-audit[ray]'") from None
    _reachable(address)
    if ray.is_initialized():  # (this process's own connection, whatever ``address`` says)
        return ray
    import logging

    try:
        with _quiet_stderr(address != "local"):
            ray.init(
                address=None if address == "local" else address,
                logging_level=logging.ERROR,
                log_to_driver=False,
                include_dashboard=False,
                configure_logging=True,
            )
    except (ConnectionError, RuntimeError, ValueError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ConfigurationError(
            f"--ray {address}: cannot connect to a Ray cluster: {first}"
        ) from None
    return ray


@contextmanager
def _quiet_stderr(quiet: bool) -> Iterator[None]:
    """Ray's native retry lines (written to file descriptor 2) left out while connecting."""
    if not quiet:
        yield
        return
    saved = os.dup(2)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _reachable(address: str) -> None:
    """A ``ray://HOST:PORT`` or ``HOST:PORT`` address answers within the timeout, or error."""
    if address in ("local", "auto"):
        return
    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    try:
        host, port = parts.hostname, parts.port
    except ValueError:
        host = port = None
    if not host or port is None or parts.scheme not in ("ray", "tcp"):
        raise ConfigurationError(
            f"--ray: expected local, auto, ray://HOST:PORT or HOST:PORT, got {address!r} "
            "(local: a Ray started here)"
        )
    try:
        socket.create_connection((host, port), timeout=RAY_CONNECT_TIMEOUT).close()
    except OSError as exc:
        why = "timed out" if isinstance(exc, TimeoutError) else exc.strerror or str(exc)
        raise ConfigurationError(
            f"--ray {address}: cannot reach the Ray cluster ({why} after at most "
            f"{RAY_CONNECT_TIMEOUT:g} s): is it running, and is the address right?"
        ) from None
