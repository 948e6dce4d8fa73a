"""Work spread over local processes or Ray tasks, results back in input order.

:func:`map_ordered` runs ``fn(item, progress)`` for each item: in this process (``jobs=1``),
in this process and a :class:`~concurrent.futures.ProcessPoolExecutor` of workers forked from a
fork server (``jobs > 1``), or as Ray tasks (``ray_address``). Workers read their inputs
themselves (an item is a path, or a path and a batch of episodes); only results travel back.
Results come back in input order whatever the order the work ends in, so the output of a
command does not depend on ``jobs``. :func:`usable_cores` is the default ``jobs`` of the command
line. How to choose: docs/scale.md.
"""

from __future__ import annotations

import os
import signal
import socket
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar
from urllib.parse import urlsplit

from .errors import ConfigurationError, EpisodeAuditError, WorkerError, WorkerWarning

__all__ = [
    "RAY_CONNECT_TIMEOUT",
    "Progress",
    "check_jobs",
    "map_ordered",
    "pooled",
    "sigint_held",
    "unpicklable",
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
    costs: Sequence[float] | None = None,
) -> Iterator[R]:
    """``fn(item, progress)`` for each of ``items``, yielded in the order of ``items``.

    ``jobs=1`` runs them here, one after another; ``jobs > 1`` (``None``: every usable core)
    in this process and ``jobs - 1`` worker processes (at most one process per item), forked
    from a fork server that imported episode-audit (nothing of this process, an env or a GL
    context, is inherited); ``ray_address`` as Ray tasks (``"local"``: a Ray started here,
    ``"auto"`` or ``"ray://HOST:PORT"``: a running cluster). ``fn`` and the items must then be
    picklable (a module-level function, or a :func:`functools.partial` of one).

    ``costs`` (one per item; default: the size of an item that is a local file's path, else 1)
    orders the work: the costliest first, so that no large item is left for the end. Progress
    from workers counts when a run of items is done.

    An :class:`~episode_audit.errors.EpisodeAuditError` ``fn`` raises is raised here, at its
    item's place in the order. Workers that cannot be started at all (a read-only
    ``/dev/shm``, an interpreter that cannot be executed) leave the work to this process, with
    a :class:`~episode_audit.errors.WorkerWarning`; a worker that ends before its results is a
    :class:`~episode_audit.errors.WorkerError`. On any exit before the end (an error,
    ``KeyboardInterrupt``, the iterator closed) the work not done is cancelled and the workers
    are stopped.

    >>> list(map_ordered(lambda item, progress: item * 2, [1, 2, 3]))
    [2, 4, 6]
    """
    work = list(items)
    if ray_address is None and not pooled(len(work), jobs, ray_address):
        for item in work:
            yield fn(item, progress)
        return
    processes = min(check_jobs(jobs), len(work))
    weights = [float(c) for c in costs] if costs is not None else [_size(i) for i in work]
    if ray_address is not None:
        runs = _chunks(weights, workers(None, ray_address))
        yield from _ray_map(fn, work, runs, ray_address, progress)
    else:
        _refuse_while_importing_main()
        yield from _pool_map(fn, work, _chunks(weights, processes), processes, progress)


def pooled(items: int, jobs: int | None, ray_address: str | None) -> bool:
    """Whether :func:`map_ordered` over ``items`` items sends work to its pool's workers.

    They take ``fn`` and the items pickled, as :mod:`multiprocessing` pickles (by reference:
    a lambda or a local function cannot go); Ray tasks (``ray_address``) pickle with
    ``cloudpickle``, which takes those too.
    """
    return ray_address is None and min(check_jobs(jobs), items) > 1


def unpicklable(value: object, *, back: bool = False) -> str | None:
    """Why ``value`` cannot be sent to another process, or ``None`` if it can; never raises.

    As :mod:`multiprocessing` sends it: to a pooled worker (:func:`pooled`), or through a
    vector env's worker pipe. ``back``: also read back from its bytes, as the receiving end
    does (an object can pickle and not unpickle: its class's ``__getattr__`` answering
    ``__getstate__`` for another object, before Python 3.11).

    >>> unpicklable(usable_cores) is None, unpicklable(lambda: 1) is None
    (True, False)
    """
    from multiprocessing.reduction import ForkingPickler

    try:
        data = ForkingPickler.dumps(value)
        if back:
            ForkingPickler.loads(data)
    except Exception as exc:  # (pickle raises what the object's reduction raises)
        try:
            return str(exc) or type(exc).__name__
        except Exception:  # (an exception whose __str__ raises)
            return type(exc).__name__
    return None


def _refuse_while_importing_main() -> None:
    """Raise if this is a worker importing the main module (a script without a main guard).

    Each worker imports the script that started the run; a call with ``jobs > 1`` at its top
    level would start workers again, from inside a worker.
    """
    import multiprocessing.process

    if getattr(multiprocessing.process.current_process(), "_inheriting", False):
        raise ConfigurationError(
            "jobs > 1 was asked for while a worker process was importing the main module: in "
            'a script, make the call under `if __name__ == "__main__":` (each worker imports '
            "the script), or pass jobs=1"
        )


@dataclass(frozen=True)
class _Done(Generic[R]):
    """What a worker sends back: the result or the expected error, and the steps it did."""

    result: R | None
    error: EpisodeAuditError | None
    steps: int

    def unwrap(self) -> R:
        if self.error is not None:
            raise self.error
        return self.result  # type: ignore[return-value]


def _call(fn: Work[T, R], chunk: Sequence[T]) -> list[_Done[R]]:
    """Run a chunk of items, counting their progress instead of reporting it."""
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


def _size(item: object) -> float:
    """An item's default cost: the size of the local file it names, else 1."""
    if isinstance(item, str | os.PathLike) and "://" not in str(os.fspath(item)):
        try:
            return float(max(1, os.path.getsize(item)))
        except (OSError, ValueError):
            pass
    return 1.0


def _chunks(costs: Sequence[float], processes: int) -> list[list[int]]:
    """The items' indices in runs, costliest first (longest-processing-time-first order).

    A run holds items of about ``1 / (8 * processes)`` of the cost not yet in a run, down to
    ``1 / (64 * processes)`` of the whole (an item above it, alone): few round trips, and the
    runs left for the end are small, so the processes end together. (A worker holds up to
    three runs, one running and two queued, which this process cannot take over at the end.)
    """
    order = sorted(range(len(costs)), key=lambda i: -costs[i])  # stable: ties in input order
    left = sum(costs)
    floor = left / (64 * processes)
    budget = left / (8 * processes)
    runs: list[list[int]] = []
    run: list[int] = []
    total = 0.0
    for i in order:
        if run and total + costs[i] > budget:
            runs.append(run)
            left -= total
            budget = max(floor, left / (8 * processes))
            run, total = [], 0.0
        run.append(i)
        total += costs[i]
    return [*runs, run] if run else runs


PRELOAD = ("__main__", "episode_audit", "pandas")
"""What the workers' fork server imports once, before it forks a worker per process (pandas,
when installed, because pyarrow imports it on a worker's first conversion of a column: half
a second per worker otherwise; a module that is not installed is skipped)."""


def _context() -> Any:
    """Workers forked from a fork server (a fresh interpreter that imported :data:`PRELOAD`).

    A worker so starts in milliseconds, with nothing of this process. Where there is no fork
    server (Windows), workers are spawned: each a fresh interpreter importing on its own.
    """
    import multiprocessing

    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    _refuse_a_long_temporary_directory()
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(list(PRELOAD))
    return context


_SOCKET = "/pymp-XXXXXXXX/listener-XXXXXXXX"
"""The fork server's socket under the temporary directory (multiprocessing's names)."""


def _refuse_a_long_temporary_directory() -> None:
    """Raise if the fork server's socket would not fit under the temporary directory.

    An AF_UNIX path holds 107 bytes (103 on macOS); where multiprocessing does not fall back
    to a shorter directory itself (``_get_base_temp_dir``, newer Pythons), the fork server
    could not start, and that came back as a worker that ended before its results.
    """
    import multiprocessing.util

    if hasattr(multiprocessing.util, "_get_base_temp_dir"):
        return
    temp = tempfile.gettempdir()
    room = (103 if sys.platform == "darwin" else 107) - len(_SOCKET)
    size = len(os.fsencode(temp))
    if size > room:
        raise ConfigurationError(
            f"jobs > 1: the temporary directory {temp} is too long a path for the workers' "
            f"socket ({size} bytes; at most {room}): set TMPDIR to a shorter folder, or run "
            "with jobs=1 (--jobs 1)"
        )


def _start_worker(environ: dict[str, str], parent: int) -> None:
    """A worker takes this process's environment variables and leaves Ctrl-C to the parent.

    The fork server's environment is this process's as it was when the server started (a
    credential set since would be missing); the parent stops the workers on Ctrl-C, so no
    traceback is printed per worker. A worker ends once its ``parent`` is gone
    (:func:`_watch_parent`).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if dict(os.environ) != environ:
        os.environ.clear()
        os.environ.update(environ)
    if os.name == "posix":  # (signal 0 only asks there)
        watch = threading.Thread(
            target=_watch_parent, args=(parent,), name="episode-audit-parent", daemon=True
        )
        watch.start()


PARENT_CHECK_S = 1.0
"""How often a worker looks whether the process it works for is still there, in seconds."""


def _watch_parent(parent: int) -> None:
    """End this worker when ``parent`` is gone: killed (SIGKILL, the OOM killer), it stops none.

    A worker is the fork server's child, not the parent's: nothing else tells it, and it would
    wait for work forever (holding the parent's stderr open, so a caller reading it hangs).
    """
    while True:
        time.sleep(PARENT_CHECK_S)
        try:
            os.kill(parent, 0)
        except ProcessLookupError:
            os._exit(1)
        except OSError:  # (not ours to signal: there all the same)
            pass


def _pool_map(
    fn: Work[T, R],
    work: Sequence[T],
    runs: Sequence[Sequence[int]],
    processes: int,
    progress: Progress | None,
) -> Iterator[R]:
    """The runs handed to ``processes - 1`` workers; this process takes runs too.

    While the first worker starts (a fork server that is not up yet imports episode-audit
    first: about a second), this process does the last runs (the cheapest) instead of
    waiting; then it takes runs as :func:`_gather` says. Workers that cannot be started at all
    (:class:`_NotStarted`: nothing was handed to them) leave the work to this process, with a
    :class:`~episode_audit.errors.WorkerWarning`.
    """
    results: dict[int, _Done[R]] = {}
    try:
        pool = _pool(processes)
    except _NotStarted as exc:
        yield from _here(fn, work, results, progress, exc)
        return
    futures: dict[int, Future[list[_Done[R]]]] = {}
    not_started: _NotStarted | None = None
    with _MANAGER_NOISE.hidden(stopping=False):
        first = _FirstSubmit(pool, fn, [work[i] for i in runs[0]])
        try:
            last = len(runs) - 1
            while last > 0 and first.starting():
                _take(runs[last], _call(fn, [work[i] for i in runs[last]]), results, progress)
                last -= 1
            try:
                futures[0] = first.future()
            except _NotStarted as exc:
                not_started = exc
            else:
                with sigint_held():
                    for k in range(1, last + 1):
                        futures[k] = _submit(pool, fn, [work[i] for i in runs[k]])
                yield from _gather(fn, work, runs, futures, progress, results)
        except BaseException as exc:
            first.wait()  # (its worker, once started, is stopped with the others)
            _stop(pool, [*futures.values(), *first.submitted()])
            if isinstance(exc, BrokenProcessPool):
                raise WorkerError(_BROKEN) from None
            raise
        pool.shutdown(wait=True)
    if not_started is not None:
        yield from _here(fn, work, results, progress, not_started)


_BROKEN = (
    "a worker process ended before it returned its results (killed, out of memory, or a crash "
    "in native code; or, in a script that asks for jobs > 1 outside "
    '`if __name__ == "__main__":`, it could not start: its error is above): run again with '
    "jobs=1 (--jobs 1) to see the failure in this process"
)


class _NotStarted(BrokenProcessPool):
    """The workers could not be started by this process: no work was handed to them.

    An error of this process's own (creating the pool's semaphores where ``/dev/shm`` is
    read-only, forking the fork server, executing the workers' interpreter), not one of a
    fork server or worker that started and then ended (that is a plain ``BrokenProcessPool``:
    its own error is above). Its message is the cause, in a few words.
    """


def _pool(processes: int) -> ProcessPoolExecutor:
    """A pool for ``processes - 1`` workers (started by the first submit), or :class:`_NotStarted`.

    The interpreter the workers run is tried first (:func:`_runnable`): multiprocessing starts
    it without looking whether it ran, and a fork server or resource tracker that never ran
    shows only later, as a broken pipe or a refused connection, at any point of the run.
    """
    context = _context()
    _runnable()
    try:
        return ProcessPoolExecutor(
            processes - 1,
            mp_context=context,
            initializer=_start_worker,
            initargs=(dict(os.environ), os.getpid()),
        )
    except OSError as exc:  # (a read-only or missing /dev/shm: their semaphores)
        raise _NotStarted(f"creating their queues: {_queues_cause(exc)}") from exc


_SEMAPHORES = "/dev/shm"
"""Where Linux makes the POSIX semaphores of multiprocessing's queues and locks."""


def _queues_cause(exc: OSError) -> str:
    """Why the pool's queues could not be made, in a few words: ``/dev/shm`` when it is why.

    The error of a semaphore not made names no file (``Read-only file system``, ``No such
    file or directory``): on Linux, a ``/dev/shm`` that is not a writable folder is named, and
    what to do.
    """
    if sys.platform.startswith("linux") and not exc.filename:
        shm = _SEMAPHORES
        if not (os.path.isdir(shm) and os.access(shm, os.W_OK)):
            said = exc.strerror or str(exc) or type(exc).__name__
            return f"{shm}: {said}: their semaphores need a writable {shm} (mount a tmpfs there)"
    return _cause(exc)


_RUNNABLE: set[str] = set()
"""The worker interpreters found to start (each tried once a process)."""


def _runnable() -> None:
    """Raise :class:`_NotStarted` if the workers' interpreter cannot be executed here.

    A fork server or spawned worker is that interpreter (``multiprocessing``'s executable);
    a worker forked from a running fork server needs no new one. It is run once, with nothing
    to do (``-I -S -c ''``: about 10 ms), the first time a process starts workers; not in a
    frozen application, whose executable is the application itself.
    """
    import multiprocessing.spawn
    import subprocess

    executable = os.fsdecode(multiprocessing.spawn.get_executable())
    if executable in _RUNNABLE or getattr(sys, "frozen", False):
        return
    try:
        subprocess.run(
            [executable, "-I", "-S", "-c", ""],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            timeout=_RUNNABLE_TIMEOUT,
            check=False,
        )
    except subprocess.TimeoutExpired:
        pass  # (it started: slow, not missing)
    except OSError as exc:
        raise _NotStarted(f"cannot execute {executable}: {exc.strerror or exc}") from exc
    _RUNNABLE.add(executable)


_RUNNABLE_TIMEOUT = 30.0
"""Seconds :func:`_runnable` waits for the interpreter's empty run (one that started)."""


def _cause(exc: OSError) -> str:
    """An operating-system error in a few words: ``Read-only file system``, with its path."""
    said = exc.strerror or str(exc) or type(exc).__name__
    return f"{exc.filename}: {said}" if exc.filename else said


def _here(
    fn: Work[T, R],
    work: Sequence[T],
    results: dict[int, _Done[R]],
    progress: Progress | None,
    why: _NotStarted,
) -> Iterator[R]:
    """The work not in ``results`` done in this process, as ``jobs=1`` does, after a warning."""
    import warnings

    warnings.warn(
        f"worker processes could not be started ({why}): the work runs in this process alone "
        "(jobs=1 (--jobs 1) does so without this warning)",
        WorkerWarning,
        stacklevel=2,
    )
    for i, item in enumerate(work):
        yield results.pop(i).unwrap() if i in results else fn(item, progress)


def _submit(pool: ProcessPoolExecutor, fn: Work[T, R], items: list[T]) -> Future[list[_Done[R]]]:
    """``items`` submitted to ``pool`` as one run; a worker that cannot start breaks the pool.

    Submitting starts a worker when one is missing. If the fork server has died (in a script
    without a main guard, importing it raised), Python 3.14 says so while authenticating to it
    (``ConnectionResetError``) where 3.13 marked the pool broken: either way a
    ``BrokenProcessPool`` here. Any other error of the operating system's (forking the fork
    server, its socket) is this process's own: :class:`_NotStarted`.
    """
    try:
        return pool.submit(_call, fn, items)
    except (ConnectionError, EOFError) as exc:
        raise BrokenProcessPool(f"a worker process could not be started ({exc})") from exc
    except OSError as exc:
        raise _NotStarted(_cause(exc)) from exc


class _FirstSubmit(Generic[R]):
    """The first run, submitted from a thread of its own, so this process works meanwhile.

    Starting the first worker can wait for the fork server's imports. The thread blocks
    Ctrl-C for itself, so the fork server and the workers it starts are never interrupted by
    it (see :func:`sigint_held`); this process still is.
    """

    def __init__(self, pool: ProcessPoolExecutor, fn: Work[Any, R], items: list[Any]) -> None:
        self._result: list[Future[list[_Done[R]]]] = []
        self._error: list[BaseException] = []

        def submit() -> None:
            if hasattr(signal, "pthread_sigmask"):
                signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
            try:
                self._result.append(_submit(pool, fn, items))
            except BaseException as exc:  # raised in the caller's thread by future()
                self._error.append(exc)

        self._thread = threading.Thread(target=submit, name="episode-audit-first-worker")
        self._thread.start()

    def starting(self) -> bool:
        """Whether the first worker is still being started."""
        return self._thread.is_alive()

    def wait(self) -> None:
        """Wait until the first worker has started (or failed to)."""
        self._thread.join()

    def submitted(self) -> list[Future[list[_Done[R]]]]:
        """The first run's future, if it was submitted."""
        return list(self._result)

    def future(self) -> Future[list[_Done[R]]]:
        """The first run's future, once submitted; what submitting raised is raised here."""
        self.wait()
        if self._error:
            raise self._error[0]
        return self._result[0]


def _gather(
    fn: Work[T, R],
    work: Sequence[T],
    runs: Sequence[Sequence[int]],
    futures: dict[int, Future[list[_Done[R]]]],
    progress: Progress | None,
    results: dict[int, _Done[R]],
) -> Iterator[R]:
    """The results in input order; waiting for a worker, this process does a run itself.

    It takes the next run no worker has started, in the runs' order (costliest first), as
    the workers do: all of them end on the smallest runs, so they end together (taking the
    last runs instead, it would meet the workers at the middle runs and wait a whole one out
    at the end). Progress is told as each run ends. ``results``: those of the items done
    already, by index.
    """
    pending = dict(futures)

    for i in range(len(work)):
        while i not in results:
            for k in [k for k, future in pending.items() if future.done()]:
                _take(runs[k], pending.pop(k).result(), results, progress)
            if i in results:
                break
            stolen = next((k for k in pending if pending[k].cancel()), None)
            if stolen is not None:
                del pending[stolen]
                _take(runs[stolen], _call(fn, [work[j] for j in runs[stolen]]), results, progress)
            else:
                wait(pending.values(), return_when=FIRST_COMPLETED)
        yield results.pop(i).unwrap()


def _take(
    run: Sequence[int],
    done: list[_Done[R]],
    results: dict[int, _Done[R]],
    progress: Progress | None,
) -> None:
    """A run's outcomes into ``results`` (by item index), their steps told to ``progress``."""
    for i, outcome in zip(run, done, strict=True):
        results[i] = outcome
        if progress is not None and outcome.steps:
            progress(outcome.steps)


@contextmanager
def sigint_held() -> Iterator[None]:
    """Ctrl-C held (blocked) in this thread meanwhile, and raised when it is let go.

    Held, not lost: a signal that comes meanwhile stays pending and is raised when unblocked.
    A blocked signal stays blocked in a program started meanwhile (the mask survives fork and
    exec): workers and their fork server started in here never see Ctrl-C (a worker still
    importing prints no traceback); this process does, and stops them. Outside the main
    thread it does nothing (Ctrl-C is the main thread's); without ``pthread_sigmask``
    (Windows) the signal is ignored meanwhile.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            yield
        finally:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _stop(pool: ProcessPoolExecutor, futures: Sequence[Future[Any]]) -> None:
    """Cancel what has not started and end the workers now (they may be mid-item)."""
    with _MANAGER_NOISE.hidden(stopping=True):
        for future in futures:
            future.cancel()
        terminate = getattr(pool, "terminate_workers", None)  # Python >= 3.14
        if terminate is not None:
            terminate()
        else:
            processes = list((getattr(pool, "_processes", None) or {}).values())
            for process in processes:
                process.terminate()
            for process in processes:  # gone before shutdown unlinks the queues' semaphores,
                process.join(timeout=10)  # which a worker still starting would fail to open
        pool.shutdown(wait=True, cancel_futures=True)
    wait(futures, timeout=0)


class _ManagerThreadNoise:
    """While a scope is open, a process pool's manager thread dying prints nothing.

    Python < 3.12's manager thread, finding a worker dead (a crash, the OOM killer, or workers
    terminated on purpose), sets an error on every work item it holds, the runs this process
    took over (cancelled) included, and dies of it (``InvalidStateError``): a traceback after
    the :class:`~episode_audit.errors.WorkerError` that says what happened, or noise while the
    workers are being stopped. One ``threading.excepthook`` is installed while any scope is
    open, in whatever threads they are, and the one found is put back after the last.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._previous: Callable[[Any], object] | None = None
        self._running = 0  # scopes hiding InvalidStateError (a jobs > 1 call under way)
        self._stopping = 0  # scopes hiding any error (workers being stopped)

    def _hook(self, args: Any) -> None:
        from concurrent.futures import InvalidStateError
        from concurrent.futures.process import _ExecutorManagerThread

        if isinstance(args.thread, _ExecutorManagerThread) and (
            self._stopping or (self._running and isinstance(args.exc_value, InvalidStateError))
        ):
            return
        (self._previous or threading.__excepthook__)(args)

    @contextmanager
    def hidden(self, *, stopping: bool) -> Iterator[None]:
        """Meanwhile, hide the manager thread's ``InvalidStateError`` (any error: ``stopping``)."""
        with self._lock:
            if not self._running + self._stopping:
                self._previous = threading.excepthook
                threading.excepthook = self._hook
            self._running += not stopping
            self._stopping += stopping
        try:
            yield
        finally:
            with self._lock:
                self._running -= not stopping
                self._stopping -= stopping
                if not self._running + self._stopping:
                    if threading.excepthook == self._hook:  # (else someone set their own since)
                        threading.excepthook = self._previous or threading.__excepthook__
                    self._previous = None


_MANAGER_NOISE = _ManagerThreadNoise()


def _ray_map(
    fn: Work[T, R],
    work: Sequence[T],
    runs: Sequence[Sequence[int]],
    address: str,
    progress: Progress | None,
) -> Iterator[R]:
    """The runs as Ray tasks (costliest first), their results in input order."""
    ray = _connect(address)
    remote = ray.remote(num_cpus=1, max_retries=0)(_call)
    refs: dict[int, Any] = {}
    try:
        for k, run in enumerate(runs):
            refs[k] = remote.remote(fn, [work[i] for i in run])
        where = {i: k for k, run in enumerate(runs) for i in run}
        results: dict[int, _Done[R]] = {}
        for i in range(len(work)):
            if i not in results:
                k = where[i]
                for j, outcome in zip(runs[k], ray.get(refs[k]), strict=True):
                    results[j] = outcome
                    if progress is not None and outcome.steps:
                        progress(outcome.steps)
            yield results.pop(i).unwrap()
    except BaseException as exc:
        for ref in refs.values():
            ray.cancel(ref, force=True)
        _settle(ray, list(refs.values()))
        if isinstance(exc, ray.exceptions.RayError) and not isinstance(
            exc,
            ray.exceptions.RayTaskError,  # (what the task raised: as it is)
        ):
            raise WorkerError(_RAY_LOST.format(type(exc).__name__)) from None
        raise


def _settle(ray: Any, refs: list[Any]) -> None:
    """Take the outcome of each of ``refs`` that ends within a second, and drop it.

    Ray prints the error of a task whose outcome nobody took ("Unhandled error") when its
    reference is dropped: after one task's worker died, the others' errors are noise.
    """
    try:
        ready, _ = ray.wait(refs, num_returns=len(refs), timeout=1.0)
    except Exception:
        return
    for ref in ready:
        try:
            ray.get(ref, timeout=0)
        except Exception:
            pass


_RAY_LOST = (
    "a Ray task ended before it returned its results ({}: its worker killed, out of memory, "
    "or a crash in native code; or its node lost): run again with jobs=1 (--jobs 1) to see "
    "the failure in this process"
)


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
    except OSError as exc:
        if "AF_UNIX path length" not in str(exc):
            raise
        raise ConfigurationError(
            f"--ray {address}: Ray's socket paths under TMPDIR ({tempfile.gettempdir()}) "
            "would be over the 107 bytes a socket path holds: set TMPDIR to a shorter folder "
            "(e.g. TMPDIR=/tmp)"
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
