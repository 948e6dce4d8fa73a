"""Replay PettingZoo evidence files game by game and compare every agent's episode.

A game (the agent-episodes of one joint reset) is the unit of replay: the env is rebuilt, reset
with the game's seed (or RNG state) and driven with the recorded actions — in the Parallel API
every live agent's next recorded action per step; in the AEC API the next recorded action of
``agent_selection``, with dead steps (``step(None)``) performed by the replay itself. Rows are
accounted exactly as the recorder did
(:class:`~episode_audit.record.pettingzoo.AECTurns`), then each agent's episode is compared
with its evidence: reset observation, observations, rewards, reward terms, ``terminated``,
``truncated``, length and outcome.

Each agent's infos are read as the recorder read them (its stream records a step as a single
env's), by a single env's replay helpers: an info that is not a mapping has no terms, terms that
cannot be read are none, a term value that is not a number is NaN, term names follow the one
rule (:func:`~episode_audit.record.rules.named_terms`: names that collide are one term, their sum;
text UTF-8 cannot encode is escaped), and a final info the ending rules cannot read gives the
ending by the flags alone (:meth:`~episode_audit.record.rules.EndingRules.classify_or_note`). No
info makes replay raise.

Where the recorded actions run out, the replay stops at ``agent_selection``'s turn and closes
the other agents' open rows (and begins those without a turn) with the env's state there, as
the recorder did when the game was cut by ``reset()`` or ``close()``. Three kinds of games were
not cut there:

- a game whose ``reset()`` raised (``error`` during ``reset``): it has no reset row and no
  step, so there is nothing to compare; its agent-episodes are ``not_replayable`` with a
  single env's reason, whether or not the replay's reset would raise;
- a game cut off by a torn file (an agent-episode without an end record): the recording went
  on, so those rows and reset rows were recorded at later turns, after an action the file does
  not hold. They cannot be replayed: the episode is ``not_replayable`` (saying which step and
  whose missing action), once everything before it compared identical;
- a game whose ``step()`` raised (``error`` during ``step``): the step that raised came after
  the game's last recorded action — the next agent's step, whose action is no row, or a dead
  step after it (the file does not say which). The recorder closed the open rows with the
  env's state when it raised, which the replay has only if the env left its state untouched
  and, where the replay performs dead steps after that action, only if the recording raised
  after them. So the rows closed after the next agent's turn following that action are
  compared up to what the file can reproduce: such a row whose observation, terms or flags
  differ makes its episode ``not_replayable``, saying so (the game, the last recorded action,
  the recorded error, and whether the replay's dead steps there raised), never ``diverged``
  (its reward, summed over steps that completed, is compared as any other). A dead step that
  raises there on replay is taken as the recorded error.

The replay's env raising where the recording's did not is a divergence, as for a single env:
a reset that raises diverges every agent-episode of the game at ``reset``; a step that raises
(any step before the last recorded action has run, whose action is a row or whose dead step
the recording completed) diverges at ``step`` every agent-episode whose rows it cut short,
naming the agent and step that raised for the other agents.

How the env is built, safely:

1. ``env_factory`` (``"module:callable"`` or a callable) given by the user; else
2. the recorded ``env_id`` when it is registered in this process's PettingZoo registry
   (PettingZoo 1.27+, the AEC or Parallel one by the file's kind), made with
   ``pettingzoo.make(api, env_id, **env_kwargs)``; an id that is not registered is not used
   and imports nothing; else
3. the recorded ``env_module`` when it is one of PettingZoo's own env modules
   (``pettingzoo.<family>.<name>_v<N>`` resolving inside the installed ``pettingzoo``
   package), calling its ``env()`` (AEC) or ``parallel_env()`` with the recorded ``env_kwargs``;
4. any other recorded module only with ``trust_entry_points=True``.
"""

from __future__ import annotations

import importlib
import json
import warnings
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import pyarrow as pa

from .._usercode import load_callable
from ..errors import ReplayError
from ..format import names as fmt
from ..format.columns import number_or_nan, one_array
from ..read import Evidence
from ..record.seeding import restore_rng_state
from .single import (
    RESET_RAISED,
    Divergence,
    EpisodeReplay,
    Status,
    _final_ending,
    _outcome_divergence,
    _recorded_terms,
    _row_ranges,
    _rules_of,
    _short,
    _terms_equal,
)

__all__ = ["build_pettingzoo_env", "replay_agents_evidence"]

KINDS = ("pettingzoo_parallel", "pettingzoo_aec")


def build_pettingzoo_env(
    layout: Mapping[str, Any],
    *,
    env_factory: str | Callable[[], Any] | None = None,
    trust_entry_points: bool = False,
) -> Any:
    """Build the PettingZoo env a file was recorded from (see the module docstring)."""
    from pettingzoo import AECEnv, ParallelEnv

    from ..record.pettingzoo import (
        KIND_PARALLEL,
        is_pettingzoo_module,
        is_registered,
        make_registered,
    )

    kind = str(layout.get("kind"))
    parallel = kind == KIND_PARALLEL
    want = ParallelEnv if parallel else AECEnv
    api = "ParallelEnv" if parallel else "AECEnv"
    env_id = layout.get("env_id")
    kwargs = layout.get("env_kwargs") or {}
    if env_factory is not None:
        factory = load_callable(env_factory) if isinstance(env_factory, str) else env_factory
        env = factory()
    elif isinstance(env_id, str) and is_registered(kind, env_id):
        try:
            env = make_registered(kind, env_id, kwargs)
        except Exception as exc:
            raise ReplayError(
                f"cannot make {env_id} with the recorded kwargs {kwargs!r}: "
                f"{type(exc).__name__}: {exc}"
            ) from None
    else:
        unknown_id = (
            f"env id {env_id!r} is not registered in this process's PettingZoo "
            f"{'parallel' if parallel else 'AEC'} registry and "
            if isinstance(env_id, str)
            else ""
        )
        module_name = layout.get("env_module")
        if not isinstance(module_name, str) or not module_name:
            raise ReplayError(
                f"{unknown_id}the file names no PettingZoo env module; pass --env-factory"
            )
        if not is_pettingzoo_module(module_name) and not trust_entry_points:
            raise ReplayError(
                f"{unknown_id}env module {module_name!r} is not one of PettingZoo's own; pass "
                "--env-factory MODULE:CALLABLE, or --trust-entry-points to import it"
            )
        try:
            with warnings.catch_warnings():  # PettingZoo 1.27 deprecates importing env modules
                warnings.simplefilter("ignore", DeprecationWarning)
                module = importlib.import_module(module_name)
            make = getattr(module, "parallel_env" if parallel else "env")
            env = make(**kwargs)
        except Exception as exc:
            raise ReplayError(
                f"cannot make {module_name} with the recorded kwargs {kwargs!r}: "
                f"{type(exc).__name__}: {exc}"
            ) from None
    if not isinstance(env, want):
        raise ReplayError(f"the env factory returned {type(env).__name__}, not a PettingZoo {api}")
    return env


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
        # AEC: (agent, its action index) where the recorded actions ran out
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


def _run_aec(env: Any, game: _Game, queues: dict[str, list[Any]], limit: int, failed: bool) -> None:
    """Drive an AEC game; ``failed``: the recorded game ended by a ``step()`` that raised.

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
            game.crash = _Crash(agent, None if dead else taken[agent] - 1, _error_text(exc))
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
        if not live or any(not queues.get(str(a)) for a in live):
            break  # the game is over, or the recording stopped here
        actions = {agent: queues[str(agent)].pop(0) for agent in live}
        try:
            obs, rewards, term, trunc, infos = env.step(actions)
        except Exception as exc:
            game.crash = _Crash(None, None, _error_text(exc))
            return
        for agent, action in actions.items():
            game.on_row(agent, action, agent_result(agent, obs, rewards, term, trunc, infos))
        for agent in env.agents:
            if str(agent) not in game.reset:
                game.on_reset(agent, obs.get(agent), infos.get(agent, {}))


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

    def all_not(reason: str) -> list[EpisodeReplay]:
        return [
            EpisodeReplay(path, int(r["episode"]), "not_replayable", 0, reason=reason)
            for r in records
        ]

    obs_codec, act_codec = ev.observation_codec, ev.action_codec
    if obs_codec is None or act_codec is None:
        return all_not("the file's spaces cannot be rebuilt")
    layout = ev.run.layout or {}
    try:
        env = build_pettingzoo_env(
            layout, env_factory=env_factory, trust_entry_points=trust_entry_points
        )
    except ReplayError as exc:
        return all_not(str(exc))
    aec = layout.get("kind") == "pettingzoo_aec"
    rules, terms_rule = _rules_of(ev.run)
    max_cycles = layout.get("max_cycles")
    all_records = ev.episodes().to_pylist()
    games: dict[int, dict[str, dict[str, Any]]] = {}
    for r in all_records:
        if r.get("game") is not None and r.get("agent") is not None:
            games.setdefault(int(r["game"]), {})[str(r["agent"])] = r
    steps = ev.steps()
    rows = _row_ranges(steps.column(fmt.COL_EPISODE).to_numpy())
    resets = ev.resets()
    reset_at = {int(e): i for i, e in enumerate(resets.column(fmt.COL_EPISODE).to_pylist())}
    done: dict[int, EpisodeReplay] = {}
    damaged = ev.damaged_episodes
    try:
        for record in records:
            index = int(record["episode"])
            if index in done:
                continue
            members = games.get(int(record["game"])) if record.get("game") is not None else None
            if not members:
                done[index] = EpisodeReplay(
                    path, index, "not_replayable", 0, reason="it belongs to no game"
                )
                continue
            if any(int(r["episode"]) in damaged for r in members.values()):
                for r in members.values():
                    done[int(r["episode"])] = EpisodeReplay(
                        path, int(r["episode"]), "not_replayable", 0, reason=_DAMAGED_GAME
                    )
                continue
            for result in _replay_game(
                env,
                aec,
                members,
                steps,
                rows,
                resets,
                reset_at,
                obs_codec,
                act_codec,
                rules,
                terms_rule,
                max_cycles if isinstance(max_cycles, int) else None,
                atol,
                path,
            ):
                done[result.episode] = result
                if progress is not None:
                    progress(result.steps)
    finally:
        env.close()
    return [done[int(r["episode"])] for r in records if int(r["episode"]) in done]


_DAMAGED_GAME = "an agent-episode of its game lost evidence in a damaged chunk (skipped by recover)"


def _replay_game(
    env: Any,
    aec: bool,
    members: dict[str, dict[str, Any]],
    steps: pa.Table,
    rows: dict[int, tuple[int, int]],
    resets: pa.Table,
    reset_at: dict[int, int],
    obs_codec: Any,
    act_codec: Any,
    rules: Any,
    terms_rule: Any,
    max_cycles: int | None,
    atol: float,
    path: str,
) -> list[EpisodeReplay]:
    first = next(iter(members.values()))
    seed, rng_state = first.get("seed"), first.get("rng_state")

    def every(
        status: Status, reason: str | None, divergence: Divergence | None = None
    ) -> list[EpisodeReplay]:
        """The same result for every agent-episode of the game (nothing of it was compared)."""
        return [
            EpisodeReplay(path, int(r["episode"]), status, 0, divergence, reason)
            for r in members.values()
        ]

    if seed is None and rng_state is None:
        return every("not_replayable", "no seed or RNG state recorded for its game's reset")
    if any(r.get("error_during") == "reset" for r in members.values()):
        return every("not_replayable", RESET_RAISED)
    queues: dict[str, list[Any]] = {}
    for agent, r in members.items():
        start, count = rows.get(int(r["episode"]), (0, 0))
        queues[agent] = (
            act_codec.decode(one_array(steps.column(fmt.COL_ACTION).slice(start, count)))
            if count
            else []
        )
    options = json.loads(first["options"]) if first.get("options") else None
    game = _Game()
    limit = sum(len(q) for q in queues.values()) + 2 * len(members) + 2
    # how the recorded game ended, if not by its rules, a reset or close (see the docstring)
    cut_kind: str | None = None
    if any(r.get("ended") is False for r in members.values()):
        cut_kind = _TORN
    elif _recorded_error(members, steps, rows) is not None:
        cut_kind = _FAILED
    try:
        if seed is None:
            restore_rng_state(env, json.loads(str(rng_state)))
        out = env.reset(seed=None if seed is None else int(seed), options=options)
    except Exception as exc:  # the recorded reset did not raise (see above): as a single env
        return every("diverged", None, Divergence(None, "reset", "a reset", _error_text(exc)))
    try:
        if aec:
            _run_aec(env, game, queues, limit, cut_kind == _FAILED)
        else:
            game.reset["__reset__"] = out
            _run_parallel(env, game, queues, limit)
    except Exception as exc:
        game.crash = _Crash(None, None, _error_text(exc))
    failure = _recorded_error(members, steps, rows) if cut_kind == _FAILED else None
    results = []
    for agent, r in members.items():
        results.append(
            _compare(
                agent,
                r,
                game,
                steps,
                rows,
                resets,
                reset_at,
                obs_codec,
                rules,
                terms_rule,
                max_cycles,
                atol,
                path,
                cut_kind,
                failure,
            )
        )
    return results


_TORN = "torn"
_FAILED = "failed"


def _error_text(exc: BaseException) -> str:
    """An exception the replay's env raised, as a single env's replay words it."""
    return f"{type(exc).__name__}: {exc}"


def _recorded_error(
    members: Mapping[str, Mapping[str, Any]], steps: pa.Table, rows: dict[int, tuple[int, int]]
) -> str | None:
    """``"Type: message"`` of the error a game's ``step()`` raised when it was recorded.

    From its ``error`` agent-episode, else from the note ``env_raised`` on the last row of one
    (a step that raised after every agent-episode had ended, see ``multiagent``).
    """
    for r in members.values():
        if r.get("outcome") == fmt.OUTCOME_ERROR and r.get("error_during") == "step":
            return f"{r.get('error_type')}: {r.get('error_message')}"
    if fmt.COL_NOTES not in steps.column_names:
        return None
    for r in members.values():
        start, count = rows.get(int(r["episode"]), (0, 0))
        notes = steps.column(fmt.COL_NOTES)[start + count - 1].as_py() if count else None
        try:
            items = json.loads(notes) if notes else []
        except ValueError:  # a garbled notes value: no error to read from it
            continue
        for item in items if isinstance(items, list) else ():
            code, _, detail = str(item).partition(": ")
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


def _compare(
    agent: str,
    record: dict[str, Any],
    game: _Game,
    steps: pa.Table,
    rows: dict[int, tuple[int, int]],
    resets: pa.Table,
    reset_at: dict[int, int],
    obs_codec: Any,
    rules: Any,
    terms_rule: Any,
    max_cycles: int | None,
    atol: float,
    path: str,
    cut_kind: str | None = None,
    failure: str | None = None,
) -> EpisodeReplay:
    index = int(record["episode"])
    start, count = rows.get(index, (0, 0))
    got = game.rows.get(agent, [])
    # rows from `turned` on (and a reset row outside `started`) were made where the game was cut
    turned = len(got) if game.turned is None else game.turned.get(agent, 0)
    torn = cut_kind == _TORN and game.stopped is not None

    def diverged(step: int | None, divergence: Divergence) -> EpisodeReplay:
        return EpisodeReplay(path, index, "diverged", 0 if step is None else step, divergence)

    def state_diverged(step: int, divergence: Divergence) -> EpisodeReplay:
        """A row's observation, terms or flags differ (its reward is the steps' own)."""
        if cut_kind == _FAILED and step >= turned:
            reason = _failed_step_reason(
                record.get("game"), game, failure or "an error", step, divergence.describe()
            )
            return EpisodeReplay(path, index, "not_replayable", step, reason=reason)
        return diverged(step, divergence)

    def cut_off(what: str, step: int) -> EpisodeReplay:
        assert game.stopped is not None
        who, action = game.stopped
        return EpisodeReplay(
            path,
            index,
            "not_replayable",
            step,
            reason=(
                f"cut off by the torn file: {what} was recorded after {who}'s step {action}, "
                "whose action is not in the file, so the replay cannot reach it "
                "(what comes before it replays identical)"
            ),
        )

    at = reset_at.get(index)
    if torn and at is not None and agent not in game.started:
        return cut_off("its reset row", 0)
    if at is not None and agent in game.reset:
        expected = one_array(resets.column(fmt.COL_OBSERVATION).slice(at, 1))
        equal, diff = obs_codec.compare(expected, obs_codec.encode([game.reset[agent]]), atol=atol)
        if not equal[0]:
            return diverged(
                None,
                Divergence.of_observation(
                    None, obs_codec.decode(expected)[0], game.reset[agent], float(diff[0]), atol
                ),
            )
    n = min(count, len(got), turned) if torn else min(count, len(got))
    if n:
        exp = steps.slice(start, n)
        obs_equal, obs_diff = obs_codec.compare(
            one_array(exp.column(fmt.COL_OBSERVATION)),
            obs_codec.encode([g[1] for g in got[:n]]),
            atol=atol,
        )
        exp_r = exp.column(fmt.COL_REWARD).to_numpy()
        exp_t = exp.column(fmt.COL_TERMINATED).to_pylist()
        exp_u = exp.column(fmt.COL_TRUNCATED).to_pylist()
        exp_terms = exp.column(fmt.COL_TERMS).to_pylist()
        extract = None if terms_rule is None else terms_rule.extractor
        for k in range(n):
            _, obs, reward, term, trunc, info = got[k]
            if not obs_equal[k]:
                exp_obs = obs_codec.decode(one_array(exp.column(fmt.COL_OBSERVATION).slice(k, 1)))[
                    0
                ]
                return state_diverged(
                    k, Divergence.of_observation(k, exp_obs, obs, float(obs_diff[k]), atol)
                )
            e = float(exp_r[k])
            if not (e == reward or (e != e and reward != reward) or abs(e - reward) <= atol):
                return diverged(k, Divergence(k, "reward", repr(e), repr(reward), abs(e - reward)))
            if extract is not None:
                found = _recorded_terms(extract, info)  # as the agent's stream recorded them
                mine = None if found is None else list(found.items())
                if not _terms_equal(exp_terms[k], mine, atol):
                    return state_diverged(
                        k,
                        Divergence(
                            k, "terms", _short(dict(exp_terms[k] or [])), _short(dict(mine or []))
                        ),
                    )
            if exp_t[k] != term:
                return state_diverged(
                    k, Divergence(k, fmt.COL_TERMINATED, str(exp_t[k]), str(term))
                )
            if exp_u[k] != trunc:
                return state_diverged(
                    k, Divergence(k, fmt.COL_TRUNCATED, str(exp_u[k]), str(trunc))
                )
    if torn and count > n:
        return cut_off(f"its step {n}", n)
    if game.crash is not None and len(got) < count:
        return diverged(len(got), game.crash.divergence(agent, len(got)))
    if len(got) != count:
        return diverged(
            n,
            Divergence(n, "length", f"{count} steps", f"{len(got)} in the replayed game"),
        )
    if (
        rules is not None
        and count
        and record["outcome"] not in (fmt.OUTCOME_INCOMPLETE, fmt.OUTCOME_ERROR)
    ):
        _, _, _, term, trunc, info = got[-1]
        if term or trunc:
            ending = _final_ending(
                rules,
                term,
                trunc,
                info,
                time_limit_hit=max_cycles is not None and count >= max_cycles,
            )
            outcome = _outcome_divergence(record, ending, count - 1)
            if outcome is not None:
                return diverged(count - 1, outcome)
    return EpisodeReplay(path, index, "identical", count)
