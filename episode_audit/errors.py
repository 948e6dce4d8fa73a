"""The exception tree of episode-audit.

Every error the library raises on purpose derives from :class:`EpisodeAuditError`::

    EpisodeAuditError
    ├── EvidenceError              an evidence file cannot be read as evidence
    │   ├── NotEvidenceError       not an MCAP file, or an MCAP file without our metadata
    │   ├── CorruptEvidenceError   damaged beyond the torn tail a crash leaves
    │   └── UnsupportedVersionError written by a newer major format version
    ├── RecorderError              the recorder was misused (e.g. stepping after close)
    ├── ConfigurationError         a wrong argument or option
    ├── ReplayError                an episode cannot be replayed (no env, no seed or RNG state)
    ├── WorkerError                a jobs > 1 worker or a Ray task ended before its results
    └── ContractViolation          an environment broke its contract (also an AssertionError)

and every warning it gives derives from :class:`EpisodeAuditWarning` (a ``UserWarning``)::

    EpisodeAuditWarning
    ├── RecorderWarning            a recorder, when it is made, over an env whose episodes it
    │                              cannot record or replay as they ran (state no file holds, an
    │                              Autoreset deeper in the chain)
    ├── RecorderTroubleWarning     recording failed (a full disk, a deleted file, no file locks);
    │                              the loop goes on (also a RuntimeWarning)
    ├── UnclosedRecorderWarning    a recorder collected without close() (also a ResourceWarning,
    │                              hidden by default as those are)
    └── WorkerWarning              a ``jobs > 1`` run done in this process: its workers could
                                   not be started

``warnings.filterwarnings("ignore", category=RecorderWarning)`` (or ``"error"``) picks them by
kind: a ``RecorderWarning`` points at the user's line that made the recorder, not at the
library, so a filter on the module ``episode_audit`` does not see it. Messages say what was
expected, what was found, and what to do.
"""

from __future__ import annotations

from os import PathLike
from typing import Any

__all__ = [
    "ConfigurationError",
    "ContractViolation",
    "CorruptEvidenceError",
    "EpisodeAuditError",
    "EpisodeAuditWarning",
    "EvidenceError",
    "NotEvidenceError",
    "RecorderError",
    "RecorderTroubleWarning",
    "RecorderWarning",
    "ReplayError",
    "UnclosedRecorderWarning",
    "UnsupportedVersionError",
    "WorkerError",
    "WorkerWarning",
]


class EpisodeAuditError(Exception):
    """Base class of every error episode-audit raises on purpose."""


class EvidenceError(EpisodeAuditError):
    """An evidence file cannot be read; the message names the file and the problem.

    The problem is cut to :data:`MAX_PROBLEM` characters: it may quote a value from the file,
    which can be megabytes long, and the message is one line on a terminal.

    >>> len(str(EvidenceError("run.mcap", "format_version " + "x" * 10**6)))
    1038
    """

    def __init__(self, path: str | PathLike[str], problem: str) -> None:
        self.path = str(path)
        if len(problem) > MAX_PROBLEM:
            problem = f"{problem[:MAX_PROBLEM]}... ({len(problem) - MAX_PROBLEM} more characters)"
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")

    def __reduce__(self) -> tuple[Any, ...]:
        # Pickled as built (a worker process sends it back): the problem is not cut again
        return (_rebuilt, (type(self), self.path, self.problem))


def _rebuilt(cls: type[EvidenceError], path: str, problem: str) -> EvidenceError:
    exc = cls.__new__(cls)
    exc.path, exc.problem = path, problem
    Exception.__init__(exc, f"{path}: {problem}")
    return exc


MAX_PROBLEM = 1000
"""The longest problem an :class:`EvidenceError` message quotes."""


class NotEvidenceError(EvidenceError):
    """The file is not an MCAP file, or not one written by episode-audit."""


class CorruptEvidenceError(EvidenceError):
    """The file is damaged in a way a crash cannot explain (bad bytes before the torn tail)."""


class UnsupportedVersionError(EvidenceError):
    """The file was written by a newer major version of the format than this reader knows."""


class RecorderError(EpisodeAuditError):
    """The recorder was misused, e.g. stepped after ``close()``."""


class ConfigurationError(EpisodeAuditError):
    """An argument or option is wrong; the message says what was expected."""


class ReplayError(EpisodeAuditError):
    """An episode cannot be replayed: no environment can be built, or no seed / RNG state."""


class WorkerError(EpisodeAuditError):
    """A worker process of a ``jobs > 1`` run (or a Ray task) ended before its results.

    It was killed, ran out of memory or crashed in native code (or its Ray node was lost), or it
    could not start: a script that asks for ``jobs > 1`` outside ``if __name__ == "__main__":``
    (each worker imports it).
    """


class EpisodeAuditWarning(UserWarning):
    """Base class of every warning episode-audit gives (filter them all by this category)."""


class RecorderWarning(EpisodeAuditWarning):
    """A recorder, when it is made, over an env whose episodes it cannot record as they ran.

    State the file cannot hold (a wrapper's running statistics, a sub-env's own state), so
    those episodes cannot be replayed; an ``Autoreset`` deeper in the chain, whose resets the
    recorder cannot see. ``check`` reports the same from the file.
    """


class RecorderTroubleWarning(EpisodeAuditWarning, RuntimeWarning):
    """Recording failed (a full disk, a file deleted or not finished, no file locks).

    Warned once, the training loop goes on, and the file's run-end record says so. Also a
    ``RuntimeWarning``: a filter on that category catches it too.
    """


class UnclosedRecorderWarning(EpisodeAuditWarning, ResourceWarning):
    """A recorder was collected without ``close()``: close it, or use it as a context manager.

    Its file is finished then (open episodes ``incomplete``), as ``close()`` would have done.
    Also a ``ResourceWarning``: hidden unless those are shown (``python -X dev``, pytest).
    """


class WorkerWarning(EpisodeAuditWarning):
    """The worker processes of a ``jobs > 1`` run could not be started: it ran in this process.

    The message says why (e.g. ``Read-only file system``: no writable ``/dev/shm`` for their
    shared semaphores, as in some containers). ``jobs=1`` does the same work without it.
    """


class ContractViolation(EpisodeAuditError, AssertionError):
    """An environment broke its contract (``episode_audit.testing``): a test failure.

    The message names each broken clause (step, term, expected vs got) and the evidence file
    kept; ``result`` is the :class:`~episode_audit.testing.ContractResult` that showed it.
    """

    def __init__(self, message: str, result: object = None) -> None:
        super().__init__(message)
        self.result = result
