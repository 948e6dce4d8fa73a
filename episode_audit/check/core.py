"""Check evidence files: pure functions from evidence to findings.

- :func:`check` opens evidence files and checks each one into a :class:`CheckResult`.
- :func:`check_evidence` checks one open :class:`~episode_audit.read.reader.Evidence`.
- :class:`Finding` is one problem (or remark) with a stable ``code``, a severity and a location.

Steps are checked a block at a time with ``pyarrow.compute`` and numpy over whole columns; no
Python code runs per step. Per-episode results are merged across blocks, so an episode that
spans several blocks gets one finding naming its first offending step. Each file is read once:
the pass over its steps also keeps its resets and episode records for the checks that follow.

Finding codes (``episode`` / ``step`` locate the first occurrence; messages give counts):

===============================  ========  ======================================================
code                             severity  meaning
===============================  ========  ======================================================
``terms_sum_mismatch``           error     a step's reward differs from the sum of its terms plus
                                           the declared constant terms by more than
                                           ``atol + rtol * |reward|``; one per episode, naming
                                           the first such step, how many and the worst residual
``missing_terms``                warning   steps without reward terms (one per file, with the
                                           count); an error with ``require_terms``; a note
                                           when recorded with ``reward_terms=None``
``nonfinite_reward``             error     NaN or infinite rewards (one per episode)
``nonfinite_term``               error     NaN or infinite reward terms (one per episode)
``observation_out_of_space``     error     observations outside the observation space (one per
                                           episode; reset observations have no step)
``action_out_of_space``          error     actions outside the action space (one per episode)
``observation_space_unchecked``  note      the observation space could not be rebuilt from the
                                           file, so observations were not checked
``action_space_unchecked``       note      the same for actions
``step_after_end``               error     rows of an episode after the row that carries its
                                           outcome, or rows the recorder noted as stepped after
                                           the episode had ended (one per episode)
``terminated_and_truncated``     note      episodes that ended with both flags set; the task
                                           ending (success or failure) counts (one per file)
``unlabeled_failure``            warning   failures without a label (one per file)
``incomplete_episode``           warning   episodes whose recording stopped before they ended,
                                           or that a torn file cut off (one per file)
``error_episode``                error     the environment raised during the episode (one per
                                           episode, with the exception type and message)
``length_mismatch``              error     an episode record's length differs from the number
                                           of its step rows (up to its outcome row)
``recorder_note:<code>``         warning   steps or resets the recorder annotated with a note
                                           ``<code>`` (e.g. ``observation_invalid``,
                                           ``term_not_numeric``, ``info_unserializable``,
                                           ``reward_not_numeric``); one per episode and code;
                                           an error for ``env_raised`` (a PettingZoo AEC env
                                           raised after every agent-episode had ended)
``file_unfinished``              warning   the writer did not finish the file (crash, kill); the
                                           message says what the reader dropped
``recorder_trouble``             error     the recorder failed inside itself while recording
                                           (warned once, never raised into the loop): the
                                           run-end record's count and first failure; the
                                           evidence may miss what it was recording then
``file_recovered``               warning   the file was rewritten by ``episode-audit recover``
                                           from a torn or damaged file; the message says what
                                           was dropped
``summary_damaged``              warning   the end of a finished file is damaged: its summary
                                           section (MCAP's index) does not match the footer's
                                           CRC, or the footer or closing magic is garbled; the
                                           file was read by scanning its data section, which
                                           holds all the evidence; ``recover`` writes a copy
                                           with a new summary
``run_end_damaged``              warning   a finished file's run-end record (which its sound
                                           summary locates) is garbled: every chunk is there,
                                           but the record's status and counts are lost;
                                           ``recover`` writes a copy with a new one
``evidence_damaged``             error     ``recover`` skipped damaged chunks of the original
                                           file: which episodes lost part or all of their
                                           evidence (one per file)
``not_replayable``               warning   episodes with neither a reset seed nor an RNG state
                                           (one per file, listing up to five); or a vector
                                           file whose vector env had no sub-envs
``missing_env_spec``             warning   the file has no environment spec to rebuild the env
``format_version``               note      the file was written with an older format version
``file_unreadable``              error     (the CLI only) an input that could not be read at
                                           all, so a JSON result never reads as ``ok`` over it
``terms_keys_changed``           note      the set of reward-term names changed from one step to
                                           the next within an episode (one per file: how many
                                           episodes, the first change and the names added and
                                           removed); steps without terms are not compared
``info_keys_changed``            note      the same for the info keys the recorder kept
                                           (``info_keys``); only steps with kept info compare
===============================  ========  ======================================================

Example:
    >>> import tempfile, pathlib, gymnasium as gym
    >>> from episode_audit import RecordEvidence
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "run.mcap"
    >>> with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=5), path) as env:
    ...     _ = env.reset(seed=1)
    ...     for _ in range(5):
    ...         _ = env.step(0)
    >>> result = check([path])
    >>> result.ok, result.episodes, result.steps
    (True, 1, 5)
    >>> [(f.severity, f.code) for f in result.findings]
    [('warning', 'missing_terms')]
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, Final, Literal

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.compute as pc

from ..format import names as fmt
from ..format.columns import null_mask, one_array
from ..format.records import from_json, listing
from ..format.spaces import SpaceCodec
from ..read import Evidence, open_evidence

__all__ = [
    "FINDING_CODES",
    "CheckResult",
    "Finding",
    "Severity",
    "check",
    "check_evidence",
    "ignored_codes",
    "is_ignored",
]

Severity = Literal["error", "warning", "note"]
_SEVERITY_RANK: dict[str, int] = {"error": 0, "warning": 1, "note": 2}

TERMS_SUM_MISMATCH = "terms_sum_mismatch"
MISSING_TERMS = "missing_terms"
NONFINITE_REWARD = "nonfinite_reward"
NONFINITE_TERM = "nonfinite_term"
OBSERVATION_OUT_OF_SPACE = "observation_out_of_space"
ACTION_OUT_OF_SPACE = "action_out_of_space"
OBSERVATION_SPACE_UNCHECKED = "observation_space_unchecked"
ACTION_SPACE_UNCHECKED = "action_space_unchecked"
STEP_AFTER_END = "step_after_end"
TERMINATED_AND_TRUNCATED = "terminated_and_truncated"
UNLABELED_FAILURE = "unlabeled_failure"
INCOMPLETE_EPISODE = "incomplete_episode"
ERROR_EPISODE = "error_episode"
LENGTH_MISMATCH = "length_mismatch"
RECORDER_NOTE = "recorder_note"
FILE_UNFINISHED = "file_unfinished"
RECORDER_TROUBLE = "recorder_trouble"
FILE_RECOVERED = "file_recovered"
SUMMARY_DAMAGED = "summary_damaged"
RUN_END_DAMAGED = "run_end_damaged"
EVIDENCE_DAMAGED = "evidence_damaged"
NOT_REPLAYABLE = "not_replayable"
MISSING_ENV_SPEC = "missing_env_spec"
FORMAT_VERSION = "format_version"
FILE_UNREADABLE = "file_unreadable"
TERMS_KEYS_CHANGED = "terms_keys_changed"
INFO_KEYS_CHANGED = "info_keys_changed"

FINDING_CODES: Final[tuple[str, ...]] = (
    TERMS_SUM_MISMATCH,
    MISSING_TERMS,
    NONFINITE_REWARD,
    NONFINITE_TERM,
    OBSERVATION_OUT_OF_SPACE,
    ACTION_OUT_OF_SPACE,
    OBSERVATION_SPACE_UNCHECKED,
    ACTION_SPACE_UNCHECKED,
    STEP_AFTER_END,
    TERMINATED_AND_TRUNCATED,
    UNLABELED_FAILURE,
    INCOMPLETE_EPISODE,
    ERROR_EPISODE,
    LENGTH_MISMATCH,
    RECORDER_NOTE,
    FILE_UNFINISHED,
    RECORDER_TROUBLE,
    FILE_RECOVERED,
    SUMMARY_DAMAGED,
    RUN_END_DAMAGED,
    EVIDENCE_DAMAGED,
    NOT_REPLAYABLE,
    MISSING_ENV_SPEC,
    FORMAT_VERSION,
    FILE_UNREADABLE,
    TERMS_KEYS_CHANGED,
    INFO_KEYS_CHANGED,
)
"""Every finding code, in the order of the module docstring's table.

``recorder_note`` stands for the whole family ``recorder_note:<code>``, whose codes are the
recorder's own (open-ended: a file may hold notes of a newer or another writer).
"""

_STEP_COLUMNS = [
    fmt.COL_EPISODE,
    fmt.COL_STEP,
    fmt.COL_ACTION,
    fmt.COL_OBSERVATION,
    fmt.COL_REWARD,
    fmt.COL_TERMS,
    fmt.COL_OUTCOME,
    fmt.COL_INFO,
    fmt.COL_NOTES,
]
_LIST_LIMIT = 5
_NOT_FINISHED = "the writer did not finish"
_HASH_MASK = (1 << 64) - 1

_IntArray = npt.NDArray[np.int64]
_BoolArray = npt.NDArray[np.bool_]
_FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Finding:
    """One thing :func:`check` found in an evidence file.

    ``episode`` and ``step`` locate the first occurrence (``None`` for a file-level finding, and
    ``step`` is ``None`` for episode-level ones and reset observations).

    >>> Finding("error", "nonfinite_reward", "reward nan at step 3", "run.mcap", 0, 3).to_dict()
    {'severity': 'error', 'code': 'nonfinite_reward', 'message': 'reward nan at step 3', \
'file': 'run.mcap', 'episode': 0, 'step': 3}
    """

    severity: Severity
    code: str
    message: str
    file: str
    episode: int | None = None
    step: int | None = None

    def to_dict(self) -> dict[str, Any]:
        """Return the finding as a JSON-able dict (keys as the dataclass fields, in order)."""
        return {
            "severity": self.severity,
            "code": self.code,
            "message": self.message,
            "file": self.file,
            "episode": self.episode,
            "step": self.step,
        }


@dataclass
class CheckResult:
    """The findings of :func:`check` over some files, with what was checked.

    :meth:`to_dict` returns this JSON shape (stable; new keys may be added, none removed)::

        {
          "ok": bool,                    # no error-severity findings
          "files": [str, ...],           # the files checked, in the order given
          "episodes": int,               # episodes checked, over all files
          "steps": int,                  # step rows checked, over all files
          "counts": {"error": int, "warning": int, "note": int},
          "findings": [                  # ordered by file, then location
            {"severity": "error" | "warning" | "note", "code": str, "message": str,
             "file": str, "episode": int | null, "step": int | null},
            ...
          ],
          "ignored": int                 # findings left out by ``ignore`` (not in counts)
        }
    """

    findings: list[Finding]
    files: list[str]
    episodes: int
    steps: int
    ignored: int = 0
    """Findings left out because their code was ignored (see :func:`check`)."""

    def _count(self, severity: str) -> int:
        return sum(1 for f in self.findings if f.severity == severity)

    @property
    def errors(self) -> int:
        """Number of error-severity findings."""
        return self._count("error")

    @property
    def warnings(self) -> int:
        """Number of warning-severity findings."""
        return self._count("warning")

    @property
    def notes(self) -> int:
        """Number of note-severity findings."""
        return self._count("note")

    @property
    def ok(self) -> bool:
        """Whether no finding has error severity."""
        return self.errors == 0

    def to_dict(self) -> dict[str, Any]:
        """Return the result in the JSON shape documented on the class."""
        return {
            "ok": self.ok,
            "files": list(self.files),
            "episodes": self.episodes,
            "steps": self.steps,
            "counts": {"error": self.errors, "warning": self.warnings, "note": self.notes},
            "findings": [f.to_dict() for f in self.findings],
            "ignored": self.ignored,
        }


# --------------------------------------------------------------------------------------------
# Per-episode accumulation across blocks
# --------------------------------------------------------------------------------------------


@dataclass
class _Hit:
    """First occurrence, count and worst value of one kind of problem in one episode."""

    step: int | None
    count: int
    worst: float = 0.0
    detail: str = ""


@dataclass
class _Hits:
    """Per (code, episode, at reset): the merged :class:`_Hit` over every block."""

    by_key: dict[tuple[str, int, bool], _Hit] = field(default_factory=dict)

    def add(
        self,
        code: str,
        episodes: _IntArray,
        first_steps: list[int | None],
        counts: _IntArray,
        worst: _FloatArray | None = None,
        details: list[str] | None = None,
    ) -> None:
        """Merge one block's per-episode results (earlier blocks keep their first step)."""
        table = self.by_key
        worst_list = None if worst is None else worst.tolist()
        for i, (episode, count) in enumerate(zip(episodes.tolist(), counts.tolist(), strict=True)):
            key = (code, episode, first_steps[i] is None)
            hit = table.get(key)
            w = 0.0 if worst_list is None else worst_list[i]
            if hit is None:
                detail = "" if details is None else details[i]
                table[key] = _Hit(first_steps[i], count, w, detail)
            else:
                hit.count += count
                if w > hit.worst or math.isnan(w):
                    hit.worst = w


def _first_per_episode(
    episode: _IntArray, mask: _BoolArray, values: _FloatArray | None = None
) -> tuple[_IntArray, _IntArray, _IntArray, _FloatArray | None]:
    """Group the rows in ``mask`` by episode.

    Return the episodes (ascending), the row of each one's first hit, its number of hits and,
    given ``values``, the largest value over its hits.
    """
    rows = np.flatnonzero(mask)
    eps = episode[rows]
    if eps.size and not (eps[1:] >= eps[:-1]).all():
        rows = rows[np.argsort(eps, kind="stable")]  # stable: first hits stay first
        eps = episode[rows]
    starts = np.flatnonzero(np.r_[True, eps[1:] != eps[:-1]]) if eps.size else rows
    counts = np.diff(np.r_[starts, eps.size]).astype(np.int64)
    largest = None if values is None else np.maximum.reduceat(values[rows], starts)
    return eps[starts], rows[starts], counts, largest


def _counts_per_episode(episode: _IntArray, ordered: bool = False) -> tuple[_IntArray, _IntArray]:
    """Return (episodes, rows per episode) of one block (``ordered``: it never decreases)."""
    if episode.size == 0:
        return episode, episode
    if ordered:
        starts = np.flatnonzero(np.r_[True, episode[1:] != episode[:-1]])
        return episode[starts], np.diff(np.r_[starts, episode.size]).astype(np.int64)
    low = int(episode.min())
    span = int(episode.max()) - low
    if 0 <= span <= 4 * episode.size:
        counts = np.bincount(episode - low, minlength=span + 1)
        present = np.flatnonzero(counts)
        return present.astype(np.int64) + low, counts[present].astype(np.int64)
    uniq, counts = np.unique(episode, return_counts=True)
    return uniq, counts.astype(np.int64)


class _KeySets:
    """Per episode, the key set of its previous step; counts the steps where it changed.

    A key set is summarised by a 64-bit signature (the wrapping sum of one hash per name), so a
    block is compared with numpy; names are looked up only for the first change in the file.
    """

    def __init__(self, code: str, noun: str) -> None:
        self.code = code
        self.noun = noun
        self.carry: dict[int, tuple[int, int]] = {}  # episode -> (signature, row) of last step
        self.carry_names: Callable[[int], list[str]] | None = None
        self.changed: set[int] = set()
        self.first: tuple[int, int, list[str], list[str]] | None = None

    def add(
        self,
        episode: _IntArray,
        step: _IntArray,
        signature: npt.NDArray[np.uint64],
        mask: _BoolArray,
        names: Callable[[int], list[str]],
    ) -> None:
        """Compare the rows in ``mask`` (``names(row)`` gives a row's keys, for messages)."""
        rows = np.flatnonzero(mask)
        if rows.size == 0:
            return
        eps = episode[rows]
        if not (eps[1:] >= eps[:-1]).all():
            order = np.argsort(eps, kind="stable")
            rows, eps = rows[order], eps[order]
        sig = signature[rows]
        boundary = eps[1:] != eps[:-1]
        first_of = np.concatenate(([True], boundary))
        previous = np.concatenate((sig[:1], sig[:-1]))
        changed = ~first_of & (sig != previous)
        from_carry: dict[int, int] = {}
        if self.carry:
            for i in np.flatnonzero(first_of).tolist():
                before = self.carry.get(int(eps[i]))
                if before is not None and before[0] != int(sig[i]):
                    changed[i] = True
                    from_carry[i] = before[1]
        if changed.any():
            hit = np.flatnonzero(changed)
            self.changed.update(eps[hit].tolist())
            if self.first is None:
                i = int(hit[0])
                old = (
                    self.carry_names(from_carry[i])
                    if i in from_carry and self.carry_names is not None
                    else names(int(rows[i - 1]))
                )
                self.first = (int(eps[i]), int(step[rows[i]]), old, names(int(rows[i])))
        last = np.concatenate((boundary, [True]))
        self.carry = dict(
            zip(
                eps[last].tolist(),
                zip(sig[last].tolist(), rows[last].tolist(), strict=True),
                strict=True,
            )
        )
        self.carry_names = names

    def finding(self, file: str) -> Finding | None:
        if self.first is None:
            return None
        episode, step, old, new = self.first
        eps = sorted(self.changed)
        added = sorted(set(new) - set(old))
        removed = sorted(set(old) - set(new))
        return Finding(
            "note",
            self.code,
            f"{self.noun} keys changed between steps in {len(eps)} episode(s) (episodes "
            f"{listing(eps)}); first at step {step} of episode {episode}: added {added}, "
            f"removed {removed}",
            file,
            episode,
            step,
        )


def _signatures(names: list[list[str] | None]) -> tuple[npt.NDArray[np.uint64], _BoolArray]:
    """A key-set signature per entry, and whether the entry has keys at all."""
    sig = np.zeros(len(names), dtype=np.uint64)
    has = np.zeros(len(names), dtype=np.bool_)
    for i, keys in enumerate(names):
        if keys:
            sig[i] = sum(hash(k) & _HASH_MASK for k in keys) & _HASH_MASK
            has[i] = True
    return sig, has


def _same_names_every_row(keys: pa.Array, rows: int, width: int) -> bool:
    """Whether ``rows`` rows of ``width`` keys each repeat the first row's keys, in order.

    The usual case, checked on the string buffers (one ``memcmp``), not string by string.
    """
    if keys.type != pa.string() or keys.null_count:
        return False
    start = keys.offset
    bounds = np.frombuffer(keys.buffers()[1], dtype=np.int32)[start : start + len(keys) + 1]
    lo, hi = int(bounds[0]), int(bounds[-1])
    row = int(bounds[width]) - lo
    if hi - lo != row * rows:
        return False
    sizes = np.diff(bounds).reshape(rows, width)
    if not bool((sizes == sizes[0]).all()):
        return False
    data = np.frombuffer(keys.buffers()[2], dtype=np.uint8, count=hi - lo, offset=lo)
    return bool((data.reshape(rows, row) == data[:row]).all())


def _short(value: Any, limit: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _number(value: float) -> str:
    return f"{value:.9g}"


# --------------------------------------------------------------------------------------------
# The checker of one file
# --------------------------------------------------------------------------------------------


class _FileCheck:
    """Checks one open evidence file; :meth:`run` returns its findings."""

    def __init__(
        self,
        ev: Evidence,
        *,
        atol: float,
        rtol: float,
        require_terms: bool,
        progress: Callable[[int], None] | None,
    ) -> None:
        self.ev = ev
        self.file = str(ev.path)
        self.atol = float(atol)
        self.rtol = float(rtol)
        self.require_terms = require_terms
        self.progress = progress
        constants = (ev.run.reward_terms or {}).get("constants") or {}
        self.constants: dict[str, float] = {
            str(k): float(v) for k, v in constants.items() if isinstance(v, (int, float))
        }
        self.constant_sum = math.fsum(self.constants.values())
        self.findings: list[Finding] = []
        self.hits = _Hits()
        self.steps = 0
        self.episodes = 0
        self.missing_terms = 0
        self.first_missing: tuple[int, int] | None = None
        self.ended: set[int] = set()
        self.max_ended: int | None = None
        self.count_parts: list[tuple[_IntArray, _IntArray]] = []
        self.obs_codec: SpaceCodec | None = ev.observation_codec
        self.act_codec: SpaceCodec | None = ev.action_codec
        self.term_keys = _KeySets(TERMS_KEYS_CHANGED, "reward-term")
        self.info_keys = _KeySets(INFO_KEYS_CHANGED, "info")

    def finding(
        self,
        severity: Severity,
        code: str,
        message: str,
        episode: int | None = None,
        step: int | None = None,
    ) -> None:
        self.findings.append(Finding(severity, code, message, self.file, episode, step))

    # ------------------------------------------------------------------ driver

    def run(self) -> list[Finding]:
        self.check_file()
        self.check_codecs()
        # One pass over the file: streaming the steps also keeps the reset blocks and the
        # episode records, so check_resets() and check_episodes() read no chunk again.
        # info is optional to the checks (files may have been made by other tools)
        optional = {fmt.COL_INFO} - set(self.ev.steps_schema.names)
        columns = [c for c in _STEP_COLUMNS if c not in optional]
        for batch in self.ev.iter_step_batches(columns=columns):
            self.check_block(batch)
            self.steps += batch.num_rows
            if self.progress is not None:
                self.progress(batch.num_rows)
        self.check_resets()
        self.check_episodes()
        self.check_unfinished()
        self.report_hits()
        self.report_missing_terms()
        for tracker in (self.term_keys, self.info_keys):
            found = tracker.finding(self.file)
            if found is not None:
                self.findings.append(found)
        self.findings.sort(
            key=lambda f: (
                -1 if f.episode is None else f.episode,
                -1 if f.step is None else f.step,
                _SEVERITY_RANK[f.severity],
                f.code,
            )
        )
        return self.findings

    # ------------------------------------------------------------------ file level

    def check_unfinished(self) -> None:
        """After the pass over the file: an unfinished file, and whether it held anything."""
        ev = self.ev
        if ev.finished:
            return
        # the reader's reason may end by saying it too ("ends at byte N without a summary: the
        # writer did not finish"): the message says it once
        why = (ev.torn or "no run-end record").removesuffix(f": {_NOT_FINISHED}")
        read = "complete chunks were read"
        if not self.steps and not self.episodes and not ev.resets().num_rows:
            read = (
                "it holds no complete chunk: no episode, reset or step to check (a recorder "
                "killed before its first flush, or one still starting)"
            )
        self.finding("warning", FILE_UNFINISHED, f"{_NOT_FINISHED} the file ({why}); {read}")

    def check_file(self) -> None:
        ev = self.ev
        troubles = (ev.run_end or {}).get(fmt.RUN_END_TROUBLE)
        if troubles:
            first = str((ev.run_end or {}).get(fmt.RUN_END_FIRST_TROUBLE) or "not recorded")
            self.finding(
                "error",
                RECORDER_TROUBLE,
                f"the recorder failed inside itself {troubles} time(s) while recording (first: "
                f"{first[:300]}); the evidence may miss what it was recording then",
            )
        if ev.finished and (ev.run_end or {}).get("status") == fmt.RUN_STATUS_RECOVERED:
            dropped = (ev.run_end or {}).get("dropped") or "not recorded"
            self.finding(
                "warning",
                FILE_RECOVERED,
                f"rewritten by episode-audit recover from a torn or damaged file; "
                f"dropped: {dropped}",
            )
            damaged, stretches = ev.damaged_episodes, ev.damaged_stretches
            if damaged or stretches:
                shown = damaged.first(_LIST_LIMIT)
                lost = (
                    f"{damaged.count} episode(s) lost part or all of their evidence "
                    f"(episodes {listing(shown, damaged.count)}): their records, steps and "
                    "outcomes are not the whole run"
                    if damaged
                    else "no episode lost evidence"
                )
                self.finding(
                    "error",
                    EVIDENCE_DAMAGED,
                    f"recover skipped {stretches} damaged stretch(es) of the original file; {lost}",
                    shown[0] if shown else None,
                )
        if ev.summary_damage:
            self.finding(
                "warning",
                SUMMARY_DAMAGED,
                f"{ev.summary_damage}: the file was read by scanning its data section, which "
                "holds all the evidence (`episode-audit recover` writes a copy with a new summary)",
            )
        if ev.run_end_damage:
            self.finding(
                "warning",
                RUN_END_DAMAGED,
                f"{ev.run_end_damage}: the writer finished the file (its summary and footer are "
                "sound) and every chunk is there, but the record's status and counts are lost "
                "(`episode-audit recover` writes a copy with a new run-end record)",
            )
        layout = ev.run.layout or {}
        if ev.run.env_spec is None and not layout.get("env_module"):  # PettingZoo: a module
            notes = [str(n) for n in (ev.run.recorder or {}).get("notes") or []]
            why = f" ({'; '.join(notes)})" if notes else ""
            self.finding(
                "warning",
                MISSING_ENV_SPEC,
                f"no environment spec recorded{why}: replay needs an env factory",
            )
        if layout.get("kind") == "vector" and layout.get("sub_envs") is False:
            why = layout.get("replay_note") or "the vector env had no sub-envs"
            self.finding("warning", NOT_REPLAYABLE, f"no episode can be replayed on its own: {why}")
        version = ev.run.format_version
        if _version_tuple(version) < _version_tuple(fmt.FORMAT_VERSION):
            self.finding(
                "note",
                FORMAT_VERSION,
                f"written with format {version}, older than the current {fmt.FORMAT_VERSION}",
            )

    def check_codecs(self) -> None:
        if self.obs_codec is None:
            self.finding(
                "note",
                OBSERVATION_SPACE_UNCHECKED,
                "the observation space cannot be rebuilt from the file; observations "
                "were not checked against it",
            )
        if self.act_codec is None:
            self.finding(
                "note",
                ACTION_SPACE_UNCHECKED,
                "the action space cannot be rebuilt from the file; actions were not checked "
                "against it",
            )

    # ------------------------------------------------------------------ steps

    def check_block(self, batch: pa.RecordBatch) -> None:
        n = batch.num_rows
        if n == 0:
            return
        episode: _IntArray = batch.column(fmt.COL_EPISODE).to_numpy(zero_copy_only=False)
        step: _IntArray = batch.column(fmt.COL_STEP).to_numpy(zero_copy_only=False)
        reward: _FloatArray = batch.column(fmt.COL_REWARD).to_numpy(zero_copy_only=False)
        ordered = bool((episode[1:] >= episode[:-1]).all())  # the usual layout
        present, counts = _counts_per_episode(episode, ordered)
        after_end = self.check_endings(batch, episode, present, ordered)
        self.check_rewards(batch, episode, step, reward)
        self.check_term_keys(batch.column(fmt.COL_TERMS), episode, step)
        if fmt.COL_INFO in batch.schema.names:
            self.check_info_keys(batch.column(fmt.COL_INFO), episode, step)
        self.check_space(fmt.COL_OBSERVATION, batch.column(fmt.COL_OBSERVATION), episode, step)
        self.check_space(fmt.COL_ACTION, batch.column(fmt.COL_ACTION), episode, step)
        noted_after_end = self.check_notes(batch.column(fmt.COL_NOTES), episode, step)
        if noted_after_end is not None:
            after_end = after_end | noted_after_end if after_end is not None else noted_after_end
        if after_end is not None and after_end.any():
            eps, first, hits, _ = _first_per_episode(episode, after_end)
            self.hits.add(STEP_AFTER_END, eps, step[first].tolist(), hits)
            present, counts = _counts_per_episode(episode[~after_end], ordered)
        self.count_parts.append((present, counts))

    def check_endings(
        self, batch: pa.RecordBatch, episode: _IntArray, present: _IntArray, ordered: bool
    ) -> _BoolArray | None:
        """Record which episodes ended; return the rows after an episode's outcome row.

        ``present`` holds the block's episodes in ascending order; ``ordered`` says whether
        ``episode`` never decreases.
        """
        outcome = batch.column(fmt.COL_OUTCOME)
        n = batch.num_rows
        after: _BoolArray | None = None
        if self.max_ended is not None and present[0] <= self.max_ended:
            seen = [e for e in present.tolist() if e in self.ended]
            if seen:
                after = np.isin(episode, np.array(seen, dtype=np.int64))
        if outcome.null_count == n:
            return after
        end_rows = np.flatnonzero(~null_mask(outcome))
        end_eps = episode[end_rows]
        self.ended.update(end_eps.tolist())
        top = int(end_eps.max())
        self.max_ended = top if self.max_ended is None else max(self.max_ended, top)
        # The usual layout: each episode's rows are contiguous and its outcome row is its last,
        # so the row after an outcome row (if any) belongs to another episode.
        following = end_rows + 1
        following[following == n] = end_rows[following == n]
        if ordered and not (episode[following] == end_eps)[following != end_rows].any():
            return after
        uniq_eps, first = np.unique(end_eps, return_index=True)
        end_pos = end_rows[first]
        k = np.minimum(np.searchsorted(uniq_eps, episode), uniq_eps.size - 1)
        within = (uniq_eps[k] == episode) & (np.arange(n) > end_pos[k])
        if within.any():
            after = within if after is None else after | within
        return after

    def check_rewards(
        self,
        batch: pa.RecordBatch,
        episode: _IntArray,
        step: _IntArray,
        reward: _FloatArray,
    ) -> None:
        finite_reward = np.isfinite(reward)
        bad_reward = ~finite_reward
        if bad_reward.any():
            eps, first, counts, _ = _first_per_episode(episode, bad_reward)
            details = [f"reward {_number(r)}" for r in reward[first].tolist()]
            self.hits.add(NONFINITE_REWARD, eps, step[first].tolist(), counts, details=details)

        terms = batch.column(fmt.COL_TERMS)
        n = batch.num_rows
        if terms.null_count:
            missing = null_mask(terms)
            count = int(missing.sum())
            if self.first_missing is None and count:
                row = int(np.argmax(missing))
                self.first_missing = (int(episode[row]), int(step[row]))
            self.missing_terms += count
            if count == n:
                return
            has_terms = ~missing
        else:
            has_terms = np.ones(n, dtype=np.bool_)

        offsets: _IntArray = terms.offsets.to_numpy(zero_copy_only=False).astype(np.int64)
        lo, hi = int(offsets[0]), int(offsets[-1])
        values: _FloatArray = terms.items.slice(lo, hi - lo).to_numpy(zero_copy_only=False)
        starts = offsets[:-1] - lo
        lengths = np.diff(offsets)
        empty = lengths == 0
        padded = np.append(values, 0.0)
        sums: _FloatArray = np.add.reduceat(padded, starts)
        sums[empty] = 0.0
        nonfinite_values = ~np.isfinite(values)
        if nonfinite_values.any():
            bad_per_row = np.add.reduceat(np.append(nonfinite_values, False), starts)
            bad_per_row[empty] = 0
            bad_term = (bad_per_row > 0) & has_terms
        else:
            bad_term = None
        if bad_term is not None and bad_term.any():
            eps, first, counts, _ = _first_per_episode(episode, bad_term)
            keys = terms.keys
            details = []
            for row in first.tolist():
                start, stop = int(offsets[row]), int(offsets[row + 1])
                segment = values[start - lo : stop - lo]
                j = int(np.flatnonzero(~np.isfinite(segment))[0])
                details.append(f"term {keys[start + j].as_py()!r} is {_number(segment[j])}")
            self.hits.add(NONFINITE_TERM, eps, step[first].tolist(), counts, details=details)

        expected = sums + self.constant_sum
        with np.errstate(invalid="ignore", over="ignore"):
            residual = np.abs(reward - expected)
            tolerance = self.atol + self.rtol * np.abs(reward)
            mismatch = has_terms & finite_reward & (residual > tolerance)
        if bad_term is not None:
            mismatch &= ~bad_term
        if not mismatch.any():
            return
        eps, first, counts, worst = _first_per_episode(episode, mismatch, residual)
        constants = f" + constants {_number(self.constant_sum)}" if self.constants else ""
        details = [
            f"reward {_number(r)} != terms sum {_number(s)}{constants} (residual {d:.3g})"
            for r, s, d in zip(
                reward[first].tolist(), sums[first].tolist(), residual[first].tolist(), strict=True
            )
        ]
        self.hits.add(
            TERMS_SUM_MISMATCH, eps, step[first].tolist(), counts, worst=worst, details=details
        )

    def check_term_keys(self, terms: pa.Array, episode: _IntArray, step: _IntArray) -> None:
        """Track the set of reward-term names from step to step (``terms_keys_changed``)."""
        if terms.null_count == len(terms):
            return
        offsets: _IntArray = terms.offsets.to_numpy(zero_copy_only=False).astype(np.int64)
        lo, hi = int(offsets[0]), int(offsets[-1])
        if hi == lo:
            return
        keys = terms.keys.slice(lo, hi - lo)
        lengths = np.diff(offsets)

        def names(row: int) -> list[str]:
            return sorted(
                str(k) for k in keys[offsets[row] - lo : offsets[row + 1] - lo].to_pylist()
            )

        n = len(terms)
        width = int(lengths[0])
        uniform = terms.null_count == 0 and width and bool((lengths == width).all())
        if uniform and (n == 1 or _same_names_every_row(keys, n, width)):
            sig, _ = _signatures([names(0)])
            every = np.ones(n, dtype=np.bool_)
            self.term_keys.add(episode, step, np.full(n, sig[0], np.uint64), every, names)
            return
        encoded = pc.dictionary_encode(keys)
        weights, _ = _signatures([[k] for k in encoded.dictionary.to_pylist()])
        per_value = weights[encoded.indices.to_numpy(zero_copy_only=False)]
        signature = np.add.reduceat(np.append(per_value, np.uint64(0)), offsets[:-1] - lo)
        mask = (lengths > 0) & ~null_mask(terms)
        self.term_keys.add(episode, step, signature.astype(np.uint64), mask, names)

    def check_info_keys(self, info: pa.Array, episode: _IntArray, step: _IntArray) -> None:
        """Track the set of kept info keys from step to step (``info_keys_changed``)."""
        if info.null_count == len(info):
            return
        encoded = pc.dictionary_encode(info)
        distinct: list[list[str] | None] = []
        for text in encoded.dictionary.to_pylist():
            try:
                value = from_json(text, "info")
            except ValueError:
                value = None
            distinct.append(sorted(str(k) for k in value) if isinstance(value, dict) else None)
        sig, has = _signatures(distinct)
        size = len(distinct)
        indices = encoded.indices.fill_null(size).to_numpy(zero_copy_only=False)
        signature = np.append(sig, np.uint64(0))[indices]
        mask = np.append(has, False)[indices]

        def names(row: int) -> list[str]:
            return distinct[int(indices[row])] or []

        self.info_keys.add(episode, step, signature, mask, names)

    def check_space(
        self, column: str, array: pa.Array, episode: _IntArray, step: _IntArray | None
    ) -> None:
        """Check a column against its space (``step`` is ``None`` for reset observations)."""
        codec = self.obs_codec if column == fmt.COL_OBSERVATION else self.act_codec
        if codec is None:
            return
        try:
            inside = codec.contains(array)
        except (TypeError, ValueError, pa.ArrowException) as exc:
            self.unchecked(column, f"{type(exc).__name__}: {exc}")
            return
        outside = ~inside
        if not outside.any():
            return
        code = OBSERVATION_OUT_OF_SPACE if column == fmt.COL_OBSERVATION else ACTION_OUT_OF_SPACE
        eps, first, counts, _ = _first_per_episode(episode, outside)
        details = []
        for row in first.tolist():
            try:
                value = codec.decode(array.slice(row, 1))[0]
            except Exception as exc:  # a value contains() judged but decode cannot show
                value = f"<{type(exc).__name__}>"
            details.append(_short(value))
        first_steps: list[int | None] = (
            [None] * len(details) if step is None else step[first].tolist()
        )
        self.hits.add(code, eps, first_steps, counts, details=details)

    def unchecked(self, column: str, why: str) -> None:
        code = (
            OBSERVATION_SPACE_UNCHECKED if column == fmt.COL_OBSERVATION else ACTION_SPACE_UNCHECKED
        )
        if column == fmt.COL_OBSERVATION:
            self.obs_codec = None
        else:
            self.act_codec = None
        self.finding("note", code, f"{column}s were not checked against their space: {why}")

    def check_notes(
        self, notes: pa.Array, episode: _IntArray, step: _IntArray | None
    ) -> _BoolArray | None:
        """Turn recorder notes into per-episode hits; return the rows noted ``step_after_end``."""
        n = len(notes)
        if notes.null_count == n:
            return None
        encoded = pc.dictionary_encode(notes)
        size = len(encoded.dictionary)
        indices = encoded.indices.fill_null(size).to_numpy(zero_copy_only=False)
        by_code: dict[str, list[tuple[int, str]]] = {}
        for slot, text in enumerate(encoded.dictionary.to_pylist()):
            for note in _parse_notes(text):
                code, _, message = note.partition(":")
                by_code.setdefault(code.strip(), []).append((slot, message.strip()))
        after_end: _BoolArray | None = None
        for code, slots in by_code.items():
            in_slot = np.zeros(size + 1, dtype=np.bool_)
            message_of: dict[int, str] = {}
            for slot, message in slots:
                in_slot[slot] = True
                message_of.setdefault(slot, message)
            mask = in_slot[indices]
            if code == STEP_AFTER_END and step is not None:
                after_end = mask
                continue
            eps, first, counts, _ = _first_per_episode(episode, mask)
            details = [message_of[int(indices[row])] for row in first.tolist()]
            first_steps: list[int | None] = (
                [None] * len(details) if step is None else step[first].tolist()
            )
            self.hits.add(f"{RECORDER_NOTE}:{code}", eps, first_steps, counts, details=details)
        return after_end

    # ------------------------------------------------------------------ resets and episodes

    def check_resets(self) -> None:
        resets = self.ev.resets()
        if resets.num_rows == 0:
            return
        episode: _IntArray = resets.column(fmt.COL_EPISODE).to_numpy()
        if fmt.COL_OBSERVATION in resets.column_names:
            obs = one_array(resets.column(fmt.COL_OBSERVATION))
            self.check_space(fmt.COL_OBSERVATION, obs, episode, None)
        if fmt.COL_NOTES in resets.column_names:
            self.check_notes(one_array(resets.column(fmt.COL_NOTES)), episode, None)

    def check_episodes(self) -> None:
        table = self.ev.episodes()
        self.episodes = table.num_rows
        if table.num_rows == 0:
            return
        rows = table.select(
            [
                "episode",
                "outcome",
                "failure_label",
                "terminated",
                "truncated",
                "length",
                "seed",
                "rng_state",
                "error_type",
                "error_message",
                "error_during",
                "ended",
            ]
        )
        episode: _IntArray = rows.column("episode").to_numpy()
        outcome = rows.column("outcome")
        length: _IntArray = rows.column("length").to_numpy()

        def listed(mask: Any) -> list[int]:
            listing: list[int] = episode[np.asarray(mask, dtype=np.bool_)].tolist()
            return listing

        both = pc.fill_null(pc.and_(rows.column("terminated"), rows.column("truncated")), False)
        both_eps = listed(both.to_numpy(zero_copy_only=False))
        if both_eps:
            self.finding(
                "note",
                TERMINATED_AND_TRUNCATED,
                f"{len(both_eps)} episode(s) ended with both terminated and truncated set; "
                f"the task ending counts (episodes {listing(both_eps)})",
                both_eps[0],
            )

        is_failure = pc.equal(outcome, fmt.OUTCOME_FAILURE)
        unlabeled = pc.and_(is_failure, pc.equal(rows.column("failure_label"), fmt.UNLABELED))
        unlabeled_eps = listed(pc.fill_null(unlabeled, False).to_numpy(zero_copy_only=False))
        if unlabeled_eps:
            failures = int(pc.sum(is_failure).as_py() or 0)
            self.finding(
                "warning",
                UNLABELED_FAILURE,
                f"{len(unlabeled_eps)} of {failures} failure(s) have no label "
                f"(episodes {listing(unlabeled_eps)})",
                unlabeled_eps[0],
            )

        ended = rows.column("ended").to_numpy(zero_copy_only=False)
        incomplete = pc.equal(outcome, fmt.OUTCOME_INCOMPLETE).to_numpy(zero_copy_only=False)
        incomplete_eps = listed(incomplete)
        if incomplete_eps:
            cut_off = incomplete & ~ended
            lost = self.ev.damaged_episodes  # (their end records were in damaged chunks)
            if lost:
                cut_off &= ~np.array([e in lost for e in rows.column(fmt.COL_EPISODE).to_pylist()])
            cut = int(cut_off.sum())
            torn = f", {cut} of them cut off by the torn end of the file" if cut else ""
            self.finding(
                "warning",
                INCOMPLETE_EPISODE,
                f"{len(incomplete_eps)} episode(s) stopped before they ended{torn} "
                f"(episodes {listing(incomplete_eps)})",
                incomplete_eps[0],
            )

        errors = pc.equal(outcome, fmt.OUTCOME_ERROR).to_numpy(zero_copy_only=False)
        if errors.any():
            for record in rows.filter(pa.array(errors)).to_pylist():
                during = record["error_during"] or "step"
                where = (
                    "during reset" if during == "reset" else f"while taking step {record['length']}"
                )
                self.finding(
                    "error",
                    ERROR_EPISODE,
                    f"the environment raised {record['error_type'] or 'an exception'} "
                    f"{where}: {record['error_message'] or ''}",
                    int(record["episode"]),
                    None if during == "reset" else int(record["length"]),
                )

        self.check_lengths(episode, length, ended)

        seedless = pc.and_(pc.is_null(rows.column("seed")), pc.is_null(rows.column("rng_state")))
        seedless_eps = listed(seedless.to_numpy(zero_copy_only=False))
        if seedless_eps:
            self.finding(
                "warning",
                NOT_REPLAYABLE,
                f"{len(seedless_eps)} episode(s) have neither a reset seed nor an RNG state "
                f"and cannot be replayed (episodes {listing(seedless_eps)})",
                seedless_eps[0],
            )

    def check_lengths(self, episode: _IntArray, length: _IntArray, ended: _BoolArray) -> None:
        if self.count_parts:
            eps = np.concatenate([p[0] for p in self.count_parts])
            counts = np.concatenate([p[1] for p in self.count_parts])
            uniq, inverse = np.unique(eps, return_inverse=True)
            totals = np.bincount(inverse, weights=counts).astype(np.int64)
        else:
            uniq = totals = np.zeros(0, dtype=np.int64)
        if uniq.size:
            k = np.minimum(np.searchsorted(uniq, episode), uniq.size - 1)
            counted = np.where(uniq[k] == episode, totals[k], 0)
        else:
            counted = np.zeros_like(episode)
        wrong = ended & (counted != length)
        for e, n, c in zip(
            episode[wrong].tolist(), length[wrong].tolist(), counted[wrong].tolist(), strict=True
        ):
            self.finding(
                "error",
                LENGTH_MISMATCH,
                f"the episode record says {n} steps, the file holds {c} step rows "
                "up to its outcome",
                e,
            )

    # ------------------------------------------------------------------ reporting

    def report_missing_terms(self) -> None:
        if not self.missing_terms:
            return
        source = (self.ev.run.reward_terms or {}).get("source")
        severity: Severity = "error" if self.require_terms else "warning"
        if source is None and not self.require_terms:
            severity = "note"  # reward_terms=None: the recording was told to keep none
        episode, step = self.first_missing or (None, None)
        self.finding(
            severity,
            MISSING_TERMS,
            f"{self.missing_terms} of {self.steps} steps have no reward terms "
            f"(terms source {source!r}); their rewards cannot be checked against terms",
            episode,
            step,
        )

    def report_hits(self) -> None:
        # A recorder note repeated across many episodes (e.g. every autoreset of a vector env)
        # is one finding naming the episodes, not one per episode.
        repeated: dict[tuple[str, bool, str], list[tuple[int, _Hit]]] = {}
        for (code, episode, at_reset), hit in self.hits.by_key.items():
            if code.startswith(RECORDER_NOTE + ":"):
                repeated.setdefault((code, at_reset, hit.detail), []).append((episode, hit))
        for (code, episode, at_reset), hit in self.hits.by_key.items():
            group = repeated.get((code, at_reset, hit.detail))
            if group is None or len(group) <= _LIST_LIMIT:
                self.findings.append(self.hit_finding(code, episode, hit))
            elif group[0][0] == episode:
                self.findings.append(self.note_summary(code, group))

    def note_summary(self, code: str, group: list[tuple[int, _Hit]]) -> Finding:
        episodes = sorted(e for e, _ in group)
        first_episode, first = min(group, key=lambda item: item[0])
        where = "at reset" if first.step is None else "on steps"
        message = (
            f"recorder noted {code.partition(':')[2]} {where} in {len(episodes)} episodes "
            f"(episodes {listing(episodes)}; {sum(h.count for _, h in group)} time(s) in all): "
            f"{first.detail}"
        )
        return Finding(_note_severity(code), code, message, self.file, first_episode, first.step)

    def hit_finding(self, code: str, episode: int, hit: _Hit) -> Finding:
        where = "at reset" if hit.step is None else f"at step {hit.step}"
        n = hit.count
        severity: Severity = "error"
        if code == TERMS_SUM_MISMATCH:
            message = (
                f"{hit.detail} {where}; {n} step(s) of the episode mismatch, worst residual "
                f"{hit.worst:.3g} (tolerance {self.atol:g} + {self.rtol:g}*|reward|)"
            )
        elif code in (NONFINITE_REWARD, NONFINITE_TERM):
            message = f"{hit.detail} {where}; {n} step(s) of the episode"
        elif code in (OBSERVATION_OUT_OF_SPACE, ACTION_OUT_OF_SPACE):
            noun = "observation" if code == OBSERVATION_OUT_OF_SPACE else "action"
            message = f"{noun} outside its space {where}: {hit.detail}; {n} row(s) of the episode"
        elif code == STEP_AFTER_END:
            message = f"{n} step(s) recorded after the episode ended, first {where}"
        else:  # recorder notes
            severity = _note_severity(code)
            noted = code.partition(":")[2]
            message = f"recorder noted {noted} {where} ({n} time(s) in the episode): {hit.detail}"
        return Finding(severity, code, message, self.file, episode, hit.step)


_ERROR_NOTES = frozenset({f"{RECORDER_NOTE}:env_raised"})
"""Recorder notes that say what an ``error`` outcome says elsewhere: the env raised."""


def _note_severity(code: str) -> Severity:
    """A recorder note's severity: a warning, unless it says the environment raised."""
    return "error" if code in _ERROR_NOTES else "warning"


def _parse_notes(text: str) -> list[str]:
    try:
        notes = from_json(text, "notes")
    except (TypeError, ValueError):
        return [f"notes_unreadable: {_short(text)}"]
    if isinstance(notes, str):
        return [notes]
    if not isinstance(notes, list):
        return [f"notes_unreadable: {_short(notes)}"]
    return [str(n) for n in notes]


def _version_tuple(version: str) -> tuple[int, ...]:
    try:
        return tuple(int(p) for p in version.split("."))
    except ValueError:
        return (0,)


# --------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------


def _check_options(atol: float, rtol: float) -> None:
    from ..errors import ConfigurationError

    for name, value in (("atol", atol), ("rtol", rtol)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
            raise ConfigurationError(f"{name}: expected a finite number >= 0, actually: {value!r}")


def ignored_codes(codes: Iterable[str], *, option: str = "ignore") -> frozenset[str]:
    """Validate finding codes to ignore; return them as a set for :func:`is_ignored`.

    A code is one of :data:`FINDING_CODES`; ``recorder_note`` stands for every recorder note,
    ``recorder_note:<code>`` for one of them. An unknown code raises
    :class:`~episode_audit.errors.ConfigurationError` naming it (under ``option``) and listing
    the known ones, so a misspelt code does not silently ignore nothing.

    >>> sorted(ignored_codes(["missing_terms", "recorder_note:observation_cast"]))
    ['missing_terms', 'recorder_note:observation_cast']
    >>> ignored_codes(["missing_term"])  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    episode_audit.errors.ConfigurationError: ignore: unknown finding code 'missing_term'; \
known codes: terms_sum_mismatch, missing_terms, ...
    """
    from ..errors import ConfigurationError

    known = frozenset(FINDING_CODES)
    wanted = [codes] if isinstance(codes, str) else list(codes)
    for code in wanted:
        family, sep, note = code.partition(":")
        if code in known or (sep and family == RECORDER_NOTE and note):
            continue
        raise ConfigurationError(
            f"{option}: unknown finding code {code!r}; known codes: {', '.join(FINDING_CODES)} "
            f"({RECORDER_NOTE} for every recorder note, {RECORDER_NOTE}:<code> for one)"
        )
    return frozenset(wanted)


def is_ignored(code: str, ignored: frozenset[str]) -> bool:
    """Whether a finding's ``code`` is among ``ignored`` (from :func:`ignored_codes`).

    >>> is_ignored("recorder_note:observation_cast", frozenset({"recorder_note"}))
    True
    """
    if not ignored:
        return False
    return code in ignored or (code.startswith(RECORDER_NOTE + ":") and RECORDER_NOTE in ignored)


def check_evidence(
    ev: Evidence,
    *,
    atol: float = 1e-6,
    rtol: float = 1e-6,
    require_terms: bool = False,
    ignore: Iterable[str] = (),
) -> list[Finding]:
    """Check one open evidence file and return its findings (see the module docstring).

    A step's terms match its reward when ``|reward - (sum(terms) + sum(constants))| <= atol +
    rtol * |reward|``, the constants being those declared in the file
    (``ev.run.reward_terms["constants"]``). With ``require_terms`` steps without terms are an
    error instead of a warning. Findings whose code is in ``ignore`` are left out, as in
    :func:`check`.
    """
    _check_options(atol, rtol)
    ignored = ignored_codes(ignore)
    found = _FileCheck(ev, atol=atol, rtol=rtol, require_terms=require_terms, progress=None).run()
    return [f for f in found if not is_ignored(f.code, ignored)]


def check(
    paths: Iterable[str | os.PathLike[str]],
    *,
    atol: float = 1e-6,
    rtol: float = 1e-6,
    require_terms: bool = False,
    ignore: Iterable[str] = (),
    progress: Callable[[int], None] | None = None,
) -> CheckResult:
    """Open and check each evidence file; return every finding with what was checked.

    An unreadable file raises :class:`~episode_audit.errors.EvidenceError` (a torn file is
    readable: it gets a ``file_unfinished`` finding). Findings whose code is in ``ignore`` are
    left out of the result (and so of its counts and ``ok``), as a linter's ignored codes are;
    :attr:`CheckResult.ignored` counts them. ``ignore`` takes the codes of
    :data:`FINDING_CODES`; ``recorder_note`` ignores every recorder note,
    ``recorder_note:<code>`` one of them; an unknown code raises
    :class:`~episode_audit.errors.ConfigurationError`. ``progress`` is called after each block
    of steps with the number of steps in that block.
    """
    _check_options(atol, rtol)
    ignored = ignored_codes(ignore)
    findings: list[Finding] = []
    files: list[str] = []
    episodes = steps = left_out = 0
    for path in paths:
        ev = open_evidence(path)
        files.append(str(ev.path))
        checker = _FileCheck(
            ev, atol=atol, rtol=rtol, require_terms=require_terms, progress=progress
        )
        for finding in checker.run():
            if is_ignored(finding.code, ignored):
                left_out += 1
            else:
                findings.append(finding)
        episodes += checker.episodes
        steps += checker.steps
    return CheckResult(findings, files, episodes, steps, left_out)
