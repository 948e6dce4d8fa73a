"""Replay one single-env or vector evidence file: its episodes, in windows of whole episodes.

:func:`replay_single_evidence` reads the file's steps once, in windows of whole episodes
(:data:`REPLAY_WINDOW_ROWS` steps or :data:`REPLAY_WINDOW_BYTES` bytes, at least one episode:
memory stays bounded), and replays each window's episodes with an
:class:`~.runner.EpisodeRunner` per sub-env (:class:`SubEnvs`): the episodes of ``env_index``
k run in recorded order through one env built for k (:func:`~.envs.build_env`), so state a
sub-env keeps across episodes evolves as it did. How episodes replay: docs/replay.md.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import replace
from typing import Any

import gymnasium as gym
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from ..errors import ReplayError
from ..format import names as fmt
from ..format.wrappers import unplaced_limits
from ..read import Evidence
from .envs import EnvFactory, build_env
from .mismatch import env_mismatch, unverified_match
from .recorded import (
    cast_actions,
    episode_records,
    layout_not_replayable,
    row_ranges,
    state_not_restorable,
    to_end,
    unrecorded_options,
    unrepeated,
)
from .results import (
    EpisodeReplay,
    none_replayable,
    not_told_from_cast,
    not_told_from_history,
    not_told_unverified,
)
from .runner import EpisodeRunner

__all__ = ["REPLAY_WINDOW_BYTES", "REPLAY_WINDOW_ROWS", "SubEnvs", "replay_single_evidence"]

REPLAY_WINDOW_ROWS = 65_536
"""Replay compares this many steps (of whole episodes) at a time, so memory stays bounded."""
REPLAY_WINDOW_BYTES = 64 << 20
"""… or fewer: as many whole episodes as this many bytes of recorded steps hold (camera
frames), and at least one episode."""


def replay_single_evidence(
    ev: Evidence,
    *,
    episodes: Iterable[int] | None = None,
    atol: float = 0.0,
    env_factory: str | EnvFactory | None = None,
    trust_entry_points: bool = False,
    progress: Callable[[int], None] | None = None,
) -> list[EpisodeReplay]:
    """Replay the episodes of one open single-env or vector evidence file."""
    wanted = None if episodes is None else set(episodes)
    why_not = layout_not_replayable(ev.run.layout) or state_not_restorable(ev.run)
    if why_not is None and env_factory is None:
        why_not = unplaced_limits(ev.run.env_spec, ev.run.layout)
    if why_not is not None:
        return none_replayable(str(ev.path), episode_records(ev, wanted), why_not)

    unverified: list[str] = []  # why the built envs' match cannot be verified

    def build() -> gym.Env[Any, Any]:
        env = build_env(ev.run, env_factory=env_factory, trust_entry_points=trust_entry_points)
        factory = env_factory is not None
        why = env_mismatch(ev.run, env, factory=factory, wrappers=trust_entry_points)
        if why is not None:
            env.close()
            raise ReplayError(why)
        cause = unverified_match(ev.run, env, factory=factory)
        if cause is not None and not unverified:
            unverified.append(cause)
        return env

    def runner(env: gym.Env[Any, Any]) -> EpisodeRunner:
        return EpisodeRunner(ev, env, atol=atol, progress=progress)

    subs = SubEnvs(build, runner)
    try:
        subs.runner(0)  # an env that cannot be built: no episode is replayable
    except ReplayError as exc:
        return none_replayable(str(ev.path), episode_records(ev, wanted), str(exc))
    try:
        results = _Pass(ev, subs, wanted).run()
    finally:
        subs.close()
    return not_told_unverified(results, unverified[0]) if unverified else results


class SubEnvs:
    """One env and its :class:`~.runner.EpisodeRunner` per sub-env, built when first needed.

    A single env's file has one (``env_index`` 0). :meth:`run_all` replays each sub-env's
    episodes in their own env, in episode order (the order a sub-env began them).
    """

    def __init__(
        self,
        build: Callable[[], gym.Env[Any, Any]],
        make_runner: Callable[[gym.Env[Any, Any]], EpisodeRunner],
    ) -> None:
        self._build = build
        self._make_runner = make_runner
        self._runners: dict[int, EpisodeRunner] = {}

    def runner(self, env_index: int) -> EpisodeRunner:
        """The runner of sub-env ``env_index`` (its env built now if it was not yet)."""
        runner = self._runners.get(env_index)
        if runner is None:
            env = self._build()
            try:
                runner = self._runners[env_index] = self._make_runner(env)
            except BaseException:
                env.close()
                raise
        return runner

    def run_all(
        self,
        records: list[dict[str, Any]],
        steps: pa.Table,
        rows: dict[int, tuple[int, int]],
        reset_rows: dict[int, int],
        resets: pa.Table,
    ) -> list[EpisodeReplay]:
        """Replay ``records``, each in its sub-env's env (see :meth:`EpisodeRunner.run_all`)."""
        by_env: dict[int, list[dict[str, Any]]] = {}
        for record in records:
            by_env.setdefault(int(record.get(fmt.COL_ENV_INDEX) or 0), []).append(record)
        out: list[EpisodeReplay] = []
        for env_index, group in sorted(by_env.items()):
            group.sort(key=lambda r: int(r[fmt.COL_EPISODE]))
            out += self.runner(env_index).run_all(group, steps, rows, reset_rows, resets)
        return out

    @property
    def raised_again(self) -> set[int]:
        """Error episodes whose step that raised raised the same in replay (any sub-env)."""
        return set().union(*(runner.raised_again for runner in self._runners.values()))

    def close(self) -> None:
        """Close every env built (each once, even if one raises)."""
        runners, self._runners = list(self._runners.values()), {}
        try:
            while runners:
                runners.pop().env.close()
        finally:
            for runner in runners:
                runner.env.close()


class _Pass:
    """One pass over a file's steps, replaying each window's episodes as it comes."""

    def __init__(self, ev: Evidence, runner: SubEnvs, wanted: set[int] | None) -> None:
        self.ev = ev
        self.runner = runner
        self.wanted = wanted
        self.results: dict[int, EpisodeReplay] = {}
        self.after_end: dict[int, int] = {}  # by episode: its rows stepped after its end
        self.unstarted: list[dict[str, Any]] = []  # records of episodes never stepped (no rows)
        self.cast: dict[int, str] = {}  # by episode: a difference the recorder's cast explains
        # records, by index, resets, reset rows: read when first needed
        self.known: list[Any] = []

    def run(self) -> list[EpisodeReplay]:
        """Every (wanted) episode's replay, in file order."""
        wanted, ev, runner, results = self.wanted, self.ev, self.runner, self.results
        selected = None if wanted is None else pa.array(sorted(wanted), pa.int64())
        for table in _windows(ev, selected):
            self.window(table)
        listed, _, resets, reset_rows = self.known
        rest = [r for r in listed if r["episode"] not in results]  # no rows at all
        if rest:
            empty = ev.steps_schema.empty_table()
            for result in runner.run_all(rest, empty, {}, reset_rows, resets):
                results[result.episode] = result
        self.in_history(listed)
        return [results[r["episode"]] for r in listed]

    def in_history(self, listed: list[dict[str, Any]]) -> None:
        """Each result, after what its (sub-)env did before it that replay does not repeat.

        An ``error`` episode's step or reset that raised is no row (a step's action is not
        recorded), and rows stepped after an episode's end are not the episode: replay does
        neither. An episode of the same env after them that differed is ``not_replayable``
        (:func:`~.results.not_told_from_history`); the episode itself says what was not
        repeated (its ``reason``, unless it has one).
        """
        vector = self.ev.run.layout.get("kind") == "vector"
        latest: dict[int, str] = {}  # by sub-env: what replay last did not repeat
        unset = unrecorded_options(self.known[2])
        for record in sorted(listed, key=lambda r: int(r[fmt.COL_EPISODE])):
            index, sub = int(record[fmt.COL_EPISODE]), int(record.get(fmt.COL_ENV_INDEX) or 0)
            result = self.results[index]
            before = latest.get(sub)
            if before is not None:
                env = f"sub-env {sub}'s env" if vector else "this env"
                result = not_told_from_history(result, before, env=env)
            again = index in self.runner.raised_again
            own = unrepeated(
                record, self.after_end.get(index, 0), raised_again=again, unset=index in unset
            )
            if index in self.cast:  # (it differed: so may its env's state after it)
                cast = f"episode {index}'s actions, stepped before the recorder cast them"
                own = cast if own is None else f"{own}, and {cast[len(f'episode {index}') :]}"
            if own is not None:
                latest[sub] = own
                if result.reason is None and result.status != "not_replayable":
                    result = replace(result, reason=f"not repeated by replay: {own}")
            self.results[index] = result

    def window(self, table: pa.Table) -> None:
        """Replay the episodes whose rows ``table`` holds (not those replayed before)."""
        known, results = self.known, self.results
        if not known:
            # After a complete pass over the steps this reads nothing again: the pass kept
            # the episode records and reset blocks. (A file longer than a window is read
            # once more here.)
            listed = episode_records(self.ev, self.wanted)
            resets = self.ev.resets()
            indices = resets.column(fmt.COL_EPISODE).to_pylist()
            reset_rows = dict(zip(indices, range(len(indices)), strict=True))
            known.extend([listed, {r["episode"]: r for r in listed}, resets, reset_rows])
            self.unstarted = [r for r in listed if int(r.get("length") or 0) == 0]
        _, by_index, resets, reset_rows = known
        rows, after_end = to_end(row_ranges(table.column(fmt.COL_EPISODE).to_numpy()), by_index)
        self.after_end.update(after_end)
        batch = [by_index[e] for e in rows if e in by_index and e not in results]
        batch = self.with_unstarted(batch)
        cast: dict[int, tuple[int, str]] | None = None
        for result in self.runner.run_all(batch, table, rows, reset_rows, resets):
            if result.status == "diverged":
                cast = cast_actions(table) if cast is None else cast
                if result.episode in cast:
                    result = not_told_from_cast(result, *cast[result.episode])
                    if result.status == "not_replayable":
                        self.cast[result.episode] = cast[result.episode][1]
            results[result.episode] = result

    def with_unstarted(self, batch: list[dict[str, Any]]) -> list[dict[str, Any]]:
        """``batch`` and the episodes reset and never stepped before it, in recorded order.

        Such an episode has no rows in any window; its (sub-)env's episodes are numbered in
        the order it ran them, so one numbered below an episode of the batch ran before it.
        Replayed after every window instead, an env that keeps state across resets would
        differ in it and in the episodes after it.
        """
        if not batch:
            return batch
        top: dict[int, int] = {}
        for record in batch:
            sub = int(record.get(fmt.COL_ENV_INDEX) or 0)
            top[sub] = max(top.get(sub, -1), int(record[fmt.COL_EPISODE]))
        chosen = {int(r[fmt.COL_EPISODE]) for r in batch}
        unstarted = [
            r
            for r in self.unstarted
            if (index := int(r[fmt.COL_EPISODE])) not in chosen
            and index not in self.results
            and index < top.get(int(r.get(fmt.COL_ENV_INDEX) or 0), -1)
        ]
        if not unstarted:
            return batch
        return sorted(batch + unstarted, key=lambda r: int(r[fmt.COL_EPISODE]))


def _windows(ev: Evidence, selected: pa.Array | None) -> Iterator[pa.Table]:
    """The file's (selected) steps in windows of whole episodes, then the last one.

    One pass over the file (memory stays bounded): the rows of a single env's episodes are
    contiguous, so all but the last window hold complete episodes. The last window is the
    steps' empty table when the file has no (selected) rows.
    """
    window: list[pa.RecordBatch] = []
    held = held_bytes = 0
    cut = 0  # where the window's last episode starts (0: it holds one episode only)
    last: Any = None  # the episode of the window's last row
    for batch in ev.iter_step_batches():
        if selected is not None:
            batch = batch.filter(pc.is_in(batch.column(fmt.COL_EPISODE), selected))
        episode = batch.column(fmt.COL_EPISODE).to_numpy()
        if episode.size:
            if last is not None and episode[0] != last:
                cut = held
            starts = np.flatnonzero(episode[1:] != episode[:-1])
            if starts.size:
                cut = held + int(starts[-1]) + 1
            last = episode[-1]
        window.append(batch)
        held += batch.num_rows
        held_bytes += batch.nbytes
        if cut and (held >= REPLAY_WINDOW_ROWS or held_bytes >= REPLAY_WINDOW_BYTES):
            table = pa.Table.from_batches(window)  # (its columns are joined as needed)
            yield table.slice(0, cut)
            window = table.slice(cut).to_batches()
            held -= cut
            held_bytes = sum(b.nbytes for b in window)
            cut = 0
    # the last window, and (with no rows) the episodes that have no steps at all
    yield pa.Table.from_batches(window) if window else ev.steps_schema.empty_table()
