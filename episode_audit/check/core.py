"""Check evidence files: pure functions from evidence to findings.

- :func:`check` opens evidence files and checks each one into a :class:`CheckResult`.
- :func:`check_evidence` checks one open :class:`~episode_audit.read.Evidence`.

One pass over a file's steps, a block at a time, runs every rule group over whole columns with
``pyarrow.compute`` and numpy (no Python code per step); per-episode results merge across
blocks, so an episode spanning several blocks gets one finding at its first offending step.
The pass also keeps the resets and episode records for the checks that follow. What each
finding code means is in ``docs/findings.md``.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import partial

import pyarrow as pa

from .._jobs import map_ordered
from ..errors import ConfigurationError, EpisodeAuditError
from ..format import names as fmt
from ..read import Evidence, open_evidence
from ..read.arguments import non_negative, path_list
from ..read.inputs import skipped
from ._state import BoolArray, FileState, FloatArray, Hit, HitMessage, IntArray, counts_per_episode
from .endings import EndingChecks
from .episodes import check_episode_records
from .facts import check_file_facts, check_unfinished
from .findings import CheckResult, Finding
from .keys import KeyChecks
from .notes import is_note, note_finding, notes_summary, recorder_notes, reset_notes
from .registry import FILE_UNREADABLE, SEVERITY_RANK, ignored_by, ignored_codes, is_ignored
from .rewards import RewardChecks
from .spaces import SpaceChecks

__all__ = ["check", "check_evidence"]

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


class _FileCheck:
    """Checks one open evidence file: the shared file state, then each rule group in turn."""

    def __init__(
        self,
        ev: Evidence,
        *,
        atol: float,
        rtol: float,
        require_terms: bool,
        progress: Callable[[int], None] | None,
    ) -> None:
        self.state = state = FileState(ev)
        self.progress = progress
        self.rewards = RewardChecks(state, atol=atol, rtol=rtol, require_terms=require_terms)
        self.spaces = SpaceChecks(state)
        self.endings = EndingChecks(state)
        self.keys = KeyChecks(state)
        self.messages: dict[str, HitMessage] = {
            **self.rewards.messages(),
            **self.spaces.messages(),
            **self.endings.messages(),
        }

    def run(self) -> list[Finding]:
        """Check the file; return its findings, ordered by location."""
        state = self.state
        check_file_facts(state)
        self.spaces.unrebuildable()
        # One pass over the file: streaming the steps also keeps the reset blocks and the
        # episode records, so the resets and the episode records read no chunk again.
        # info is optional to the checks (files may have been made by other tools)
        optional = {fmt.COL_INFO} - set(state.ev.steps_schema.names)
        columns = [c for c in _STEP_COLUMNS if c not in optional]
        for batch in state.ev.iter_step_batches(columns=columns):
            self.block(batch)
            state.steps += batch.num_rows
            if self.progress is not None:
                self.progress(batch.num_rows)
        self.resets()
        check_episode_records(state, self.endings)
        check_unfinished(state)
        self.report_hits()
        self.rewards.missing_terms_finding()
        self.rewards.rewards_changed_finding()
        self.keys.findings()
        state.findings.sort(
            key=lambda f: (
                -1 if f.episode is None else f.episode,
                -1 if f.step is None else f.step,
                SEVERITY_RANK[f.severity],
                f.code,
            )
        )
        return state.findings

    def block(self, batch: pa.RecordBatch) -> None:
        """Run every rule group over one block of steps."""
        if batch.num_rows == 0:
            return
        episode: IntArray = batch.column(fmt.COL_EPISODE).to_numpy(zero_copy_only=False)
        step: IntArray = batch.column(fmt.COL_STEP).to_numpy(zero_copy_only=False)
        reward: FloatArray = batch.column(fmt.COL_REWARD).to_numpy(zero_copy_only=False)
        ordered = bool((episode[1:] >= episode[:-1]).all())  # the usual layout
        present, counts = counts_per_episode(episode, ordered)
        outcome = batch.column(fmt.COL_OUTCOME)
        after_end = self.endings.rows_after_end(outcome, episode, present, ordered)
        terms = batch.column(fmt.COL_TERMS)
        self.rewards.block(terms, episode, step, reward)
        self.keys.terms(terms, episode, step)
        if fmt.COL_INFO in batch.schema.names:
            self.keys.info(batch.column(fmt.COL_INFO), episode, step)
        self.spaces.column(fmt.COL_OBSERVATION, batch.column(fmt.COL_OBSERVATION), episode, step)
        self.spaces.column(fmt.COL_ACTION, batch.column(fmt.COL_ACTION), episode, step)
        noted: BoolArray | None = recorder_notes(
            self.state, batch.column(fmt.COL_NOTES), episode, step
        )
        if noted is not None:
            after_end = after_end | noted if after_end is not None else noted
        self.endings.count_rows(episode, step, after_end, present, counts, ordered)

    def resets(self) -> None:
        """The reset observations against their space, and the resets' recorder notes."""
        # block by block: one column of every reset observation, and what checking it against
        # its space makes, would take several times their memory (image observations)
        records = self.state.ev.episodes()
        never_ran = frozenset(
            records.column("episode").filter(self.state.unstarted).to_pylist()
            if records.num_rows
            else ()
        )
        for resets in self.state.ev.resets().to_batches():
            if resets.num_rows == 0:
                continue
            episode: IntArray = resets.column(fmt.COL_EPISODE).to_numpy()
            if fmt.COL_OBSERVATION in resets.schema.names:
                obs = resets.column(fmt.COL_OBSERVATION)
                self.spaces.column(fmt.COL_OBSERVATION, obs, episode, None)
            if fmt.COL_NOTES in resets.schema.names:
                recorder_notes(self.state, reset_notes(resets, never_ran), episode, None)

    def report_hits(self) -> None:
        """The per-episode findings, from the hits merged over the blocks.

        A recorder note repeated across many episodes (e.g. every autoreset of a vector env)
        is one finding naming the episodes, not one per episode.
        """
        state = self.state
        repeated: dict[tuple[str, bool, str], list[tuple[int, Hit]]] = {}
        for (code, episode, at_reset), hit in state.hits.by_key.items():
            if is_note(code):
                repeated.setdefault((code, at_reset, hit.detail), []).append((episode, hit))
        for (code, episode, at_reset), hit in state.hits.by_key.items():
            group = repeated.get((code, at_reset, hit.detail))
            if group is None or len(group) <= _LIST_LIMIT:
                where = "at reset" if hit.step is None else f"at step {hit.step}"
                message = self.messages.get(code)
                if message is None:
                    note_finding(state, code, episode, hit, where)
                else:
                    state.finding(code, message(hit, where), episode, hit.step)
            elif group[0][0] == episode:
                notes_summary(state, code, group)


def _check_options(atol: float, rtol: float) -> None:
    non_negative("atol", atol)
    non_negative("rtol", rtol)


def check_evidence(
    ev: Evidence,
    *,
    atol: float = 1e-6,
    rtol: float = 1e-6,
    require_terms: bool = False,
    ignore: Iterable[str] = (),
) -> list[Finding]:
    """Check one open evidence file and return its findings (see ``docs/findings.md``).

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
    keep_going: bool = False,
    on_error: Callable[[EpisodeAuditError], None] | None = None,
    jobs: int | None = 1,
    ray_address: str | None = None,
) -> CheckResult:
    """Open and check each evidence file; return every finding with what was checked.

    An unreadable file raises :class:`~episode_audit.errors.EvidenceError` (a torn file is
    readable: it gets a ``file_unfinished`` finding). With ``keep_going`` it does not stop the
    others: it is listed in :attr:`CheckResult.unreadable` and :attr:`CheckResult.files`, and
    gets a ``file_unreadable`` error finding, so the result is not ``ok``; ``on_error`` is told
    of each such error as it happens. (A :class:`~episode_audit.errors.ConfigurationError` is
    raised all the same.)

    Findings whose code is in ``ignore`` are left out of the result (and so of its counts and
    ``ok``), as a linter's ignored codes are; :attr:`CheckResult.ignored` counts them.
    ``ignore`` takes the codes of :data:`FINDING_CODES`; ``recorder_note`` ignores every
    recorder note, ``recorder_note:<code>`` one of them; an unknown code raises
    :class:`~episode_audit.errors.ConfigurationError`. ``progress`` is called after each block
    of steps with the number of steps in that block.

    ``jobs`` files are checked at a time, each in a worker process (``None``: one per usable
    core), or as Ray tasks on ``ray_address`` (see :func:`~episode_audit._jobs.map_ordered`);
    the result is the same as with ``jobs=1``.

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
    >>> [(f.severity, f.code) for f in result.findings]  # CartPole reports no terms
    [('note', 'missing_terms')]
    """
    _check_options(atol, rtol)
    ignored = ignored_codes(ignore)
    result = CheckResult(
        findings=[], files=[], episodes=0, steps=0, ignored_by=dict.fromkeys(sorted(ignored), 0)
    )
    one = partial(_check_path, atol=atol, rtol=rtol, require_terms=require_terms)
    paths = path_list(paths)
    checked_files = map_ordered(one, paths, jobs=jobs, ray_address=ray_address, progress=progress)
    for path, checked in zip(paths, checked_files, strict=True):
        found = checked.findings
        if checked.error is not None:
            exc = checked.error
            result.unreadable.append(skipped(path, exc, keep_going=keep_going, on_error=on_error))
            found = [Finding("error", FILE_UNREADABLE, str(exc), str(path), None, None)]
        else:
            result.episodes += checked.episodes
            result.steps += checked.steps
        result.files.append(checked.file)
        for finding in found:
            by = ignored_by(finding.code, ignored)
            if by is not None:
                result.ignored += 1
                result.ignored_by[by] += 1
            else:
                result.findings.append(finding)
    return result


@dataclass(frozen=True)
class _Checked:
    """One file checked (in a worker, maybe): its findings and counts, or why it was not."""

    file: str
    findings: list[Finding]
    episodes: int = 0
    steps: int = 0
    error: EpisodeAuditError | None = None


def _check_path(
    path: str | os.PathLike[str],
    progress: Callable[[int], None] | None,
    *,
    atol: float,
    rtol: float,
    require_terms: bool,
) -> _Checked:
    """Open and check one file (a ``ConfigurationError`` is raised, not kept)."""
    try:
        ev = open_evidence(path)
        checker = _FileCheck(
            ev, atol=atol, rtol=rtol, require_terms=require_terms, progress=progress
        )
        found = checker.run()
    except ConfigurationError:
        raise
    except EpisodeAuditError as exc:
        return _Checked(str(path), [], error=exc)
    return _Checked(str(ev.path), found, checker.state.episodes, checker.state.steps)
