"""Replay PettingZoo evidence files game by game and compare every agent's episode.

:func:`replay_agents_evidence` replays a file's (selected) agent-episodes a whole game at a time
in the env :func:`~.envs.build_pettingzoo_env` builds: each game is reset as recorded and driven
with the recorded actions (AEC: :func:`_run_aec`, Parallel: :func:`_run_parallel`), its rows
accounted as the recorder accounted them; then each agent's episode is compared with its
evidence (:class:`_AgentEpisode`). How games replay, and what a game cut by a torn file or by a
``step()`` that raised can be compared with: docs/replay.md.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import pyarrow as pa

from ..errors import ReplayError
from ..format import names as fmt
from ..format.columns import number_or_nan, one_array
from ..format.records import EpisodeRanges, from_json, note_items
from ..format.spaces import SpaceCodec
from ..read import Evidence
from ..record.rules import EndingRules, RewardTerms
from ..record.seeding import restore_rng_state
from .compare import outcome_difference, terms_equal
from .envs import build_pettingzoo_env
from .mismatch import agents_mismatch, unverified_match
from .recorded import (
    cast_actions,
    first_noted,
    reset_options,
    row_ranges,
    rules_of,
    unrecorded_options,
)
from .results import (
    RESET_RAISED,
    Divergence,
    EpisodeReplay,
    env_error,
    none_replayable,
    not_told_from_cast,
    not_told_unverified,
    options_not_held,
    restored_state,
    short,
)
from .returned import encoded, recorded_terms

__all__ = ["replay_agents_evidence"]

KINDS = ("pettingzoo_parallel", "pettingzoo_aec")


@dataclass(frozen=True)
class _Crash:
    """Where the replay's env raised, and what.

    ``agent``'s step ``step`` (``None``: its dead step); ``agent`` ``None``: outside an agent's
    step (a Parallel step, or a call of the replay's own accounting).
    """

    agent: str | None
    step: int | None
    error: str

    def place(self) -> tuple[str, int | None]:
        """(agent, step) of an agent's step, for :func:`_turn_name`."""
        assert self.agent is not None
        return self.agent, self.step

    def divergence(self, agent: str, step: int) -> Divergence:
        """``agent``'s episode, whose row ``step`` the replay could not complete."""
        got = self.error
        if self.agent is not None and (self.agent, self.step) != (agent, step):
            got += f" (raised in {_turn_name(*self.place())})"
        return Divergence(step, "step", "a step", got)


def _turn_name(agent: str, step: int | None) -> str:
    return f"{agent}'s dead step" if step is None else f"{agent}'s step {step}"


class _Game:
    """The replayed rows of one game, per agent."""

    def __init__(self) -> None:
        self.reset: dict[str, Any] = {}
        self.rows: dict[str, list[tuple[Any, Any, float, bool, bool, Any]]] = {}
        self.crash: _Crash | None = None
        # AEC: rows and reset rows made at real turns, before the game was cut (None: not cut)
        self.turned: dict[str, int] | None = None
        self.started: set[str] = set()
        # (agent, its action index) where the recorded actions ran out (Parallel: the first
        # live agent without one)
        self.stopped: tuple[str, int] | None = None
        # AEC: (agent, its action index) of the last recorded action the replay took
        self.last: tuple[str, int] | None = None
        # AEC: the agents whose dead steps the replay performed after the game was cut
        self.dead_after_cut: list[str] = []

    def cut(self) -> None:
        """Mark what was replayed so far as made at real turns; what follows closes the game."""
        self.turned = {agent: len(rows) for agent, rows in self.rows.items()}
        self.started = set(self.reset)

    def on_reset(self, agent: str, obs: Any, info: Any) -> None:
        self.reset.setdefault(str(agent), obs)

    def on_row(
        self, agent: str, action: Any, result: tuple[Any, float, bool, bool, Any], _: Any = None
    ) -> None:
        obs, reward, term, trunc, info = result
        self.rows.setdefault(str(agent), []).append(
            (action, obs, number_or_nan(reward), _truth(term), _truth(trunc), info)
        )


def _truth(flag: Any) -> bool:
    """A flag's truth value; False for one without any (an array), as the recorder takes it."""
    try:
        return bool(flag)
    except Exception:
        return False


def _run_aec(
    env: Any,
    game: _Game,
    queues: dict[str, list[Any]],
    limit: int,
    failed: bool,
    dead_steps: bool = True,
) -> None:
    """Drive an AEC game; ``failed``: the recorded game ended by a ``step()`` that raised.

    ``dead_steps``: once the recorded actions are all taken, step the agents that are done
    (``env.agent_iter()``'s loop does), rather than end the game there (a loop that stopped
    at the game's end, then reset or closed the env).

    In such a game the recording raised after its last recorded action, so the game is cut
    (:meth:`_Game.cut`) at the turn that follows it, once that agent's turn has come (the
    recording had that turn too). A dead step the replay performs after the cut may be the
    one that raised: it is noted, and if it raises, that is the recorded error. Any other step
    that raises is a divergence (the recording completed it).
    """
    from ..record.pettingzoo import AECTurns

    turns = AECTurns(env, game.on_reset, game.on_row)
    turns.begin(list(env.agents))
    taken: dict[str, int] = {}
    left = sum(len(queue) for queue in queues.values())
    for _ in range(limit):
        if not env.agents:
            break
        agent = str(env.agent_selection)
        dead = env.terminations.get(agent, False) or env.truncations.get(agent, False)
        queue = queues.get(agent, [])
        if not dead and not queue:
            # the recording stopped here (or its next action was lost): the agent's turn came
            turns.arrive()
            game.stopped = (agent, taken.get(agent, 0))
            break
        if dead and not left and not dead_steps:
            break
        action = None if dead else queue.pop(0)
        if not dead:
            taken[agent] = taken.get(agent, 0) + 1
            game.last = (agent, taken[agent] - 1)
            left -= 1
        turns.turn(action)
        past = failed and dead and not left  # at or after the step the recording raised in
        if past and game.turned is None:
            game.cut()
        try:
            env.step(action)
        except Exception as exc:
            game.crash = _Crash(agent, None if dead else taken[agent] - 1, env_error(exc))
            if past:  # the recorded error, raised again
                turns.failed()
            return
        if past:
            game.dead_after_cut.append(agent)
        turns.stepped()
    if game.turned is None:
        game.cut()
    turns.finish()


def _run_parallel(env: Any, game: _Game, queues: dict[str, list[Any]], limit: int) -> None:
    from ..record.pettingzoo import agent_result

    obs, infos = game.reset.pop("__reset__")
    for agent in env.agents:
        game.on_reset(agent, obs.get(agent), infos.get(agent, {}))
    for _ in range(limit):
        live = list(env.agents)
        if not live:
            break  # the game is over
        out = next((str(a) for a in live if not queues.get(str(a))), None)
        if out is not None:  # the recording stopped here (a torn file: maybe amid this step)
            game.cut()
            game.stopped = (out, len(game.rows.get(out, ())))
            break
        actions = {agent: queues[str(agent)].pop(0) for agent in live}
        try:
            obs, rewards, term, trunc, infos = env.step(actions)
        except Exception as exc:
            game.crash = _Crash(None, None, env_error(exc))
            return
        for agent, action in actions.items():
            game.on_row(agent, action, agent_result(agent, obs, rewards, term, trunc, infos))
        for agent in env.agents:
            if str(agent) not in game.reset:
                game.on_reset(agent, obs.get(agent), infos.get(agent, {}))


@dataclass(frozen=True)
class _File:
    """What a PettingZoo file recorded, as its games' replays read it."""

    path: str
    aec: bool
    games: dict[int, dict[str, dict[str, Any]]]  # each game's records, by agent
    steps: pa.Table
    rows: dict[int, tuple[int, int]]
    resets: pa.Table
    reset_at: dict[int, int]
    damaged: EpisodeRanges
    obs_codec: SpaceCodec
    act_codec: SpaceCodec
    rules: EndingRules | None
    terms_rule: RewardTerms | None
    max_cycles: int | None
    atol: float
    unset_options: dict[int, str]  # by agent-episode: reset options the file does not hold
    rendered_from: int | None  # the first game whose rows are noted ``rendered``

    def typed_options(self, episode: int) -> str | None:
        """The typed form of ``episode``'s reset options (its reset row's), if any."""
        at = self.reset_at.get(episode)
        if at is None or fmt.COL_OPTIONS_TYPED not in self.resets.column_names:
            return None
        typed: str | None = self.resets.column(fmt.COL_OPTIONS_TYPED)[at].as_py()
        return typed

    @classmethod
    def read(cls, ev: Evidence, obs_codec: SpaceCodec, act_codec: SpaceCodec, atol: float) -> _File:
        """Read ``ev``'s games, steps and resets."""
        layout = ev.run.layout or {}
        rules, terms_rule = rules_of(ev.run)
        max_cycles = layout.get("max_cycles")
        games: dict[int, dict[str, dict[str, Any]]] = {}
        for r in ev.episodes().to_pylist():
            if r.get("game") is not None and r.get("agent") is not None:
                games.setdefault(int(r["game"]), {})[str(r["agent"])] = r
        steps = ev.steps()
        resets = ev.resets()
        return cls(
            str(ev.path),
            layout.get("kind") == "pettingzoo_aec",
            games,
            steps,
            row_ranges(steps.column(fmt.COL_EPISODE).to_numpy()),
            resets,
            {int(e): i for i, e in enumerate(resets.column(fmt.COL_EPISODE).to_pylist())},
            ev.damaged_episodes,
            obs_codec,
            act_codec,
            rules,
            terms_rule,
            max_cycles if isinstance(max_cycles, int) else None,
            atol,
            unrecorded_options(resets),
            _rendered_from(games, (steps, resets)),
        )


def _rendered_from(
    games: Mapping[int, Mapping[str, Mapping[str, Any]]], tables: Iterable[pa.Table]
) -> int | None:
    """The first game a row or reset row of which is noted ``rendered``, or ``None``."""
    game_of = {int(r["episode"]): g for g, members in games.items() for r in members.values()}
    found = [game_of.get(e) for table in tables for e in first_noted(table, _RENDERED)]
    return min((game for game in found if game is not None), default=None)


_RENDERED = "rendered"


def _render_cause(game: int) -> str:
    return (
        f"the recording called render() (first in game {game}), which replay does not: an "
        "env's steps may depend on it (pistonball's observations are the screen render() "
        "redraws); record without render() calls to verify them"
    )


def replay_agents_evidence(
    ev: Evidence,
    *,
    episodes: Iterable[int] | None = None,
    atol: float = 0.0,
    env_factory: str | Callable[[], Any] | None = None,
    trust_entry_points: bool = False,
    progress: Callable[[int], None] | None = None,
) -> list[EpisodeReplay]:
    """Replay the (selected) agent-episodes of a PettingZoo file, whole games at a time."""
    path = str(ev.path)
    records = ev.episodes().to_pylist()
    if episodes is not None:
        wanted = set(episodes)
        records = [r for r in records if r["episode"] in wanted]
    obs_codec, act_codec = ev.observation_codec, ev.action_codec
    if obs_codec is None or act_codec is None:
        return none_replayable(path, records, "the file's spaces cannot be rebuilt")
    try:
        env = build_pettingzoo_env(
            ev.run.layout or {}, env_factory=env_factory, trust_entry_points=trust_entry_points
        )
    except ReplayError as exc:
        return none_replayable(path, records, str(exc))
    factory = env_factory is not None
    why = agents_mismatch(ev.run.layout or {}, ev.run, env, factory=factory)
    if why is not None:
        env.close()
        return none_replayable(path, records, why)
    cause = unverified_match(ev.run, env, factory=factory)
    file = _File.read(ev, obs_codec, act_codec, atol)
    try:
        done = _replay_games(env, file, records, progress)
    finally:
        env.close()
    results = [done[int(r["episode"])] for r in records if int(r["episode"]) in done]
    return results if cause is None else not_told_unverified(results, cause)


_DAMAGED_GAME = "an agent-episode of its game lost evidence in a damaged chunk (skipped by recover)"


def _replay_games(
    env: Any,
    file: _File,
    records: list[dict[str, Any]],
    progress: Callable[[int], None] | None,
) -> dict[int, EpisodeReplay]:
    """Replay the game of each of ``records`` (once per game), by episode index."""
    done: dict[int, EpisodeReplay] = {}
    cast: dict[int, tuple[int, str]] | None = None  # (read at the first difference)
    played = 0  # the games the env was reset for so far
    for record in records:
        index = int(record["episode"])
        if index in done:
            continue
        members = file.games.get(int(record["game"])) if record.get("game") is not None else None
        if not members:
            done[index] = EpisodeReplay(
                file.path, index, "not_replayable", 0, reason="it belongs to no game"
            )
            continue
        if any(int(r["episode"]) in file.damaged for r in members.values()):
            for result in none_replayable(file.path, members.values(), _DAMAGED_GAME):
                done[result.episode] = result
            continue
        results, reset = _replay_game(env, file, members)
        if reset:
            first = next(iter(members.values()))
            restored = restored_state(first, played, unit="game")
            results = [
                r if r.status != "diverged" else replace(r, restored=restored) for r in results
            ]
            played += 1
        if any(r.status == "diverged" for r in results):
            cast = cast_actions(file.steps) if cast is None else cast
            results = _cast_explains(cast, members, results)
        if file.rendered_from is not None and int(record["game"]) >= file.rendered_from:
            results = not_told_unverified(results, _render_cause(file.rendered_from))
        for result in results:
            done[result.episode] = result
            if progress is not None:
                progress(result.steps)
    return done


def _cast_explains(
    cast: dict[int, tuple[int, str]],
    members: dict[str, dict[str, Any]],
    results: list[EpisodeReplay],
) -> list[EpisodeReplay]:
    """The game's results, its differences ``not_replayable`` if the recorder cast an action.

    Any agent's cast action (``action_cast``) changed the game every agent plays on from that
    turn, whose place among the other agents' steps the rows do not say: every difference in
    the game is then no verdict. ``cast``: :func:`~.recorded.cast_actions` of the file.
    """
    found = [cast[e] for r in members.values() if (e := int(r["episode"])) in cast]
    if not found:
        return results
    note = found[0][1]
    return [not_told_from_cast(r, 0, note) for r in results]


_TORN = "torn"
_FAILED = "failed"


def _replay_game(
    env: Any, file: _File, members: dict[str, dict[str, Any]]
) -> tuple[list[EpisodeReplay], bool]:
    """Replay one game (its records by agent) and compare each agent's episode.

    Also says whether the env was reset for it (not for a game the file cannot replay).
    """
    first = next(iter(members.values()))
    seed, rng_state = first.get("seed"), first.get("rng_state")
    if seed is None and rng_state is None:
        reason = "no seed or RNG state recorded for its game's reset"
        return none_replayable(file.path, members.values(), reason), False
    if any(r.get("error_during") == "reset" for r in members.values()):
        return none_replayable(file.path, members.values(), RESET_RAISED), False
    unset = [
        file.unset_options[e]
        for r in members.values()
        if (e := int(r["episode"])) in file.unset_options
    ]
    if unset:
        return none_replayable(file.path, members.values(), options_not_held(unset[0])), False
    queues: dict[str, list[Any]] = {}
    for agent, r in members.items():
        start, count = file.rows.get(int(r["episode"]), (0, 0))
        queues[agent] = (
            file.act_codec.decode(one_array(file.steps.column(fmt.COL_ACTION).slice(start, count)))
            if count
            else []
        )
    try:
        options = reset_options(first.get("options"), file.typed_options(int(first["episode"])))
        state: Any = None if seed is not None else from_json(str(rng_state), "rng_state")
    except ValueError as exc:
        reason = f"its game's reset record: {exc}"
        return none_replayable(file.path, members.values(), reason), False
    # how the recorded game ended, if not by its rules, a reset or close (see docs/replay.md)
    cut_kind: str | None = None
    failure: str | None = None
    if any(r.get("ended") is False for r in members.values()):
        cut_kind = _TORN
    else:
        failure = _recorded_error(members, file.steps, file.rows)
        cut_kind = None if failure is None else _FAILED
    play = _Play(env, file, members, queues, (seed, options, state), cut_kind, failure)
    results = play.run(dead_steps=True)
    if file.aec and cut_kind is None and any(r.status == "diverged" for r in results):
        # the recording may have ended the game at its last action, without the dead steps
        again = play.run(dead_steps=False)
        if not any(r.status == "diverged" for r in again):
            return again, True
    return results, True


@dataclass(frozen=True)
class _Play:
    """One game replayed from its recorded reset and actions: each agent's episode compared."""

    env: Any
    file: _File
    members: dict[str, dict[str, Any]]
    queues: dict[str, list[Any]]
    reset: tuple[Any, Any, Any]  # seed, options, RNG state (when no seed)
    cut_kind: str | None
    failure: str | None

    def run(self, *, dead_steps: bool) -> list[EpisodeReplay]:
        """Reset, replay (AEC: with or without the ``dead_steps`` after the last action)."""
        env, file, members = self.env, self.file, self.members
        seed, options, state = self.reset
        queues = {agent: list(queue) for agent, queue in self.queues.items()}
        game = _Game()
        limit = sum(len(q) for q in queues.values()) + 2 * len(members) + 2
        try:
            if seed is None:
                restore_rng_state(env, state)
            out = env.reset(seed=None if seed is None else int(seed), options=options)
        except Exception as exc:  # the recorded reset did not raise (see above): as a single env
            divergence = Divergence(None, "reset", "a reset", env_error(exc))
            return [
                EpisodeReplay(file.path, int(r["episode"]), "diverged", 0, divergence)
                for r in members.values()
            ]
        try:
            if file.aec:
                _run_aec(env, game, queues, limit, self.cut_kind == _FAILED, dead_steps)
            else:
                game.reset["__reset__"] = out
                _run_parallel(env, game, queues, limit)
        except Exception as exc:
            game.crash = _Crash(None, None, env_error(exc))
        return [
            _AgentEpisode(agent, r, game, file, self.cut_kind, self.failure).result()
            for agent, r in members.items()
        ]


def _recorded_error(
    members: Mapping[str, Mapping[str, Any]], steps: pa.Table, rows: dict[int, tuple[int, int]]
) -> str | None:
    """``"Type: message"`` of the error a game's ``step()`` raised when it was recorded.

    From its ``error`` agent-episode, else from the note ``env_raised`` on the last row of one
    (a step that raised after every agent-episode had ended, see ``record.pettingzoo``).
    """
    for r in members.values():
        if r.get("outcome") == fmt.OUTCOME_ERROR and r.get("error_during") == "step":
            return f"{r.get('error_type')}: {r.get('error_message')}"
    if fmt.COL_NOTES not in steps.column_names:
        return None
    for r in members.values():
        start, count = rows.get(int(r["episode"]), (0, 0))
        notes = steps.column(fmt.COL_NOTES)[start + count - 1].as_py() if count else None
        for item in (note_items(notes) if notes else None) or ():  # (garbled: no error in it)
            code, _, detail = item.partition(": ")
            if code == _ENV_RAISED:
                return detail.rpartition(" (during step: ")[0] or detail
    return None


_ENV_RAISED = "env_raised"


def _failed_step_reason(game_index: Any, game: _Game, error: str, step: int, what: str) -> str:
    """Why row ``step``, closed when the recorded game's ``step()`` raised, cannot be compared.

    ``what`` describes the difference. The step that raised came after the game's last recorded
    action (``game.last``): the replay stopped at the next agent's turn, whose action is not in
    the file (that step raised), or performed dead steps there that did not raise (the file
    does not say whether the recording raised in one of them or at the turn after them).
    """
    after = "its reset" if game.last is None else _turn_name(*game.last)
    dead = ", ".join(_turn_name(agent, None) for agent in game.dead_after_cut)
    if game.crash is not None:
        replay_did = f"it raised {game.crash.error} too, in {_turn_name(*game.crash.place())}"
        replay_did += f" (after {dead})" if dead else ""
    elif dead:
        replay_did = f"it did not (it performed {dead})"
    elif game.stopped is not None:
        replay_did = (
            f"it stops at {_turn_name(*game.stopped)}, which raised: its action is not in the file"
        )
    else:
        replay_did = "its game is over there"
    return (
        f"game {game_index}, after {after} (the game's last recorded action): recorded: the "
        f"env raised {error} here; replay: {replay_did}, so its step {step}, closed with the "
        f"env's state when the env raised, cannot be compared ({what})"
    )


class _AgentEpisode:
    """One agent's episode of a replayed game, compared with its evidence.

    ``cut_kind``: how the recorded game ended, if it was cut (torn, or a ``step()`` that raised
    with ``failure``, its ``"Type: message"``); rows the replay made where the game was cut
    can be compared only up to what the file can reproduce (docs/replay.md).
    """

    def __init__(
        self,
        agent: str,
        record: dict[str, Any],
        game: _Game,
        file: _File,
        cut_kind: str | None,
        failure: str | None,
    ) -> None:
        self.agent = agent
        self.record = record
        self.game = game
        self.file = file
        self.cut_kind = cut_kind
        self.failure = failure
        self.index = int(record["episode"])
        self.start, self.count = file.rows.get(self.index, (0, 0))
        self.got = game.rows.get(agent, [])
        # rows from `turned` on (and a reset row outside `started`) were made where the game
        # was cut
        self.turned = len(self.got) if game.turned is None else game.turned.get(agent, 0)
        self.torn = cut_kind == _TORN and game.stopped is not None

    def result(self) -> EpisodeReplay:
        """The episode's replay: its first difference, or identical."""
        agent, game, count, got = self.agent, self.game, self.count, self.got
        at = self.file.reset_at.get(self.index)
        if self.torn and at is not None and agent not in game.started:
            return self._cut_off("its reset row", 0)
        if at is not None and agent in game.reset:
            divergence = self._reset_divergence(at, game.reset[agent])
            if divergence is not None:
                return self._diverged(None, divergence)
        n = min(count, len(got), self.turned) if self.torn else min(count, len(got))
        if n:
            found = self._first_row_difference(n)
            if found is not None:
                return found
        if self.torn and count > n:
            return self._cut_off(f"its step {n}", n)
        if game.crash is not None and len(got) < count:
            return self._diverged(len(got), game.crash.divergence(agent, len(got)))
        if len(got) != count:
            return self._diverged(
                n,
                Divergence(n, "length", f"{count} steps", f"{len(got)} in the replayed game"),
            )
        if count:
            _, _, _, term, trunc, info = got[-1]
            max_cycles = self.file.max_cycles
            outcome = outcome_difference(
                self.file.rules,
                self.record,
                term,
                trunc,
                count - 1,
                info,
                time_limit_hit=max_cycles is not None and count >= max_cycles,
            )
            if outcome is not None:
                return self._diverged(count - 1, outcome)
        return EpisodeReplay(self.file.path, self.index, "identical", count)

    def _diverged(self, step: int | None, divergence: Divergence) -> EpisodeReplay:
        steps = 0 if step is None else step
        return EpisodeReplay(self.file.path, self.index, "diverged", steps, divergence)

    def _state_diverged(self, step: int, divergence: Divergence) -> EpisodeReplay:
        """A row's observation, terms or flags differ (its reward is the steps' own)."""
        if self.cut_kind == _FAILED and step >= self.turned:
            reason = _failed_step_reason(
                self.record.get("game"),
                self.game,
                self.failure or "an error",
                step,
                divergence.describe(),
            )
            return EpisodeReplay(self.file.path, self.index, "not_replayable", step, reason=reason)
        return self._diverged(step, divergence)

    def _cut_off(self, what: str, step: int) -> EpisodeReplay:
        assert self.game.stopped is not None
        who, action = self.game.stopped
        when = "after" if self.file.aec else "in the same step() as"
        return EpisodeReplay(
            self.file.path,
            self.index,
            "not_replayable",
            step,
            reason=(
                f"cut off by the torn file: {what} was recorded {when} {who}'s step {action}, "
                "whose action is not in the file, so the replay cannot reach it "
                "(what comes before it replays identical)"
            ),
        )

    def _reset_divergence(self, at: int, obs: Any) -> Divergence | None:
        """How the replayed reset observation ``obs`` differs from reset row ``at``, if it does."""
        obs_codec, atol = self.file.obs_codec, self.file.atol
        expected = one_array(self.file.resets.column(fmt.COL_OBSERVATION).slice(at, 1))
        equal, diff = obs_codec.compare(expected, encoded(obs_codec, [obs]), atol=atol)
        if equal[0]:
            return None
        return Divergence.of_observation(
            None, obs_codec.decode(expected)[0], obs, float(diff[0]), atol
        )

    def _first_row_difference(self, n: int) -> EpisodeReplay | None:
        """The result of the first of the first ``n`` rows that differs, if one does."""
        obs_codec, atol, got = self.file.obs_codec, self.file.atol, self.got
        exp = self.file.steps.slice(self.start, n)
        obs_equal, obs_diff = obs_codec.compare(
            one_array(exp.column(fmt.COL_OBSERVATION)),
            encoded(obs_codec, [g[1] for g in got[:n]]),
            atol=atol,
        )
        exp_r = exp.column(fmt.COL_REWARD).to_numpy()
        exp_t = exp.column(fmt.COL_TERMINATED).to_pylist()
        exp_u = exp.column(fmt.COL_TRUNCATED).to_pylist()
        exp_terms = exp.column(fmt.COL_TERMS).to_pylist()
        terms_rule = self.file.terms_rule
        extract = None if terms_rule is None else terms_rule.extractor
        for k in range(n):
            _, obs, reward, term, trunc, info = got[k]
            if not obs_equal[k]:
                column = exp.column(fmt.COL_OBSERVATION)
                exp_obs = obs_codec.decode(one_array(column.slice(k, 1)))[0]
                return self._state_diverged(
                    k, Divergence.of_observation(k, exp_obs, obs, float(obs_diff[k]), atol)
                )
            e = float(exp_r[k])
            if not (e == reward or (e != e and reward != reward) or abs(e - reward) <= atol):
                return self._diverged(
                    k, Divergence(k, "reward", repr(e), repr(reward), abs(e - reward))
                )
            if extract is not None:
                found = recorded_terms(extract, info)  # as the agent's stream recorded them
                mine = None if found is None else list(found.items())
                if not terms_equal(exp_terms[k], mine, atol):
                    expected, replayed = short(dict(exp_terms[k] or [])), short(dict(mine or []))
                    return self._state_diverged(k, Divergence(k, "terms", expected, replayed))
            if exp_t[k] != term:
                return self._state_diverged(
                    k, Divergence(k, fmt.COL_TERMINATED, str(exp_t[k]), str(term))
                )
            if exp_u[k] != trunc:
                return self._state_diverged(
                    k, Divergence(k, fmt.COL_TRUNCATED, str(exp_u[k]), str(trunc))
                )
        return None
