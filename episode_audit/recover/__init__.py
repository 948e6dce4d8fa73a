"""Recover a torn or damaged evidence file: rewrite it as a finished, indexed MCAP file.

:func:`recover` copies every complete, intact chunk of the input into a new file and finishes it
(indexes, summary, footer, a run-end record with ``status=recovered``); the
:class:`RecoveryResult` says what was kept and what dropped. What is kept, how damage is named
and the exit codes: ``docs/cli.md`` ("recover"); the run-end record: ``docs/format.md``.

- :mod:`.rewrite`: :func:`recover`, step by step;
- :mod:`.copying`: the record walk that copies the input's records into the new file;
- :mod:`.kept`: which episodes of the output were cut off, and which lost evidence;
- :mod:`.result`: :class:`RecoveryResult` and its words; :mod:`.files`: the output's checks
  and its atomic move into place.
"""

from .result import RecoveryResult
from .rewrite import recover

__all__ = ["RecoveryResult", "recover"]
