"""The evidence file format: the layer every other wing builds on (see ``docs/format.md``).

- :mod:`.names` — topics, encodings, metadata keys, column names, outcomes (spelled once).
- :mod:`.records` — the run metadata (:class:`RunInfo`), episode record schemas, JSON helpers.
- :mod:`.run_end` — the run-end record read back, its values typed (:class:`.run_end.RunEnd`).
- :mod:`.columns` — Arrow columns and value helpers shared by the recorder and replay.
- :mod:`.options` — reset options as data: what plain JSON changes, and their exact tagged JSON.
- :mod:`.spaces` — Gymnasium spaces <-> Arrow columns (codecs, buffers, descriptions).
- :mod:`.paths` — a path argument, checked once (the recorders' and the readers').

It imports nothing from the other wings.
"""

from .names import FORMAT_MAJOR, FORMAT_VERSION
from .records import EpisodeRanges, RunInfo

__all__ = ["FORMAT_MAJOR", "FORMAT_VERSION", "EpisodeRanges", "RunInfo"]
