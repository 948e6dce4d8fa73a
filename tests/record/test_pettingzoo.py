"""PettingZoo recording (record/pettingzoo/), replay (replay/pettingzoo.py) and reporting.

Real PettingZoo envs: tictactoe and connect four (AEC, action masks), rock-paper-scissors and
knights-archers-zombies (Parallel; KAZ agents die and leave mid-game). Ground truth comes from a
twin env stepped by hand with the same seed and actions, summing what PettingZoo reported in
``env.rewards`` after every step.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import sys
import time
import warnings
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pettingzoo
import pytest
from pettingzoo import AECEnv
from pettingzoo.utils.wrappers import BaseParallelWrapper, BaseWrapper
from typer.testing import CliRunner

from episode_audit import (
    ConfigurationError,
    RecordAECEvidence,
    RecordParallelEvidence,
    check,
    open_evidence,
    recover,
    replay,
    report,
)
from episode_audit.cli import app
from episode_audit.record.pettingzoo import env_id_of, env_module_of
from episode_audit.report.games import game_outcome
from tests.support.hostile import rewrite

with warnings.catch_warnings():  # PettingZoo 1.27 deprecates the env modules (for make())
    warnings.simplefilter("ignore", DeprecationWarning)
    from pettingzoo.butterfly import knights_archers_zombies_v11 as kaz
    from pettingzoo.classic import connect_four_v3, rps_v2, tictactoe_v3
    from pettingzoo.test import api_test, parallel_api_test

SEEDS = [0, 1, 2, 3]
KAZ_KWARGS = {"max_cycles": 300, "max_zombies": 6}
KAZ_SEEDS = [1, 2]  # in game 1 (seed 1) archer_0 dies 5 steps before the others
REGISTRY_IDS = {
    tictactoe_v3: "classic/tictactoe-v3",
    connect_four_v3: "classic/connect_four-v3",
    rps_v2: "classic/rps-v2",
    kaz: "butterfly/knights_archers_zombies-v11",
}


def _returns(path: Path) -> dict[tuple[int, str], float]:
    return {
        (r["game"], r["agent"]): r["return"] for r in open_evidence(path).episodes().to_pylist()
    }


# ------------------------------------------------------------------------------- AEC


def _play_aec(env: Any, seed: int) -> list[Any]:
    """A game with random legal actions (action masks); returns the actions, dead steps as None."""
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    actions: list[Any] = []
    for _agent in env.agent_iter():
        obs, _, term, trunc, _ = env.last()
        if term or trunc:
            action = None
        else:
            action = int(rng.choice(np.flatnonzero(obs["action_mask"])))
        actions.append(action)
        env.step(action)
    return actions


def _aec_truth(make: Any, seed: int, actions: list[Any]) -> dict[str, float]:
    """Per-agent sums of ``env.rewards`` over every step of a twin env."""
    env = make()
    env.reset(seed=seed)
    total: dict[str, float] = defaultdict(float)
    for action in actions:
        env.step(action)
        for agent, reward in env.rewards.items():
            total[agent] += float(reward)
    return dict(total)


@pytest.mark.parametrize("module", [tictactoe_v3, connect_four_v3])
def test_aec_games_returns_replay_and_check(tmp_path: Path, module: Any) -> None:
    path = tmp_path / "aec.mcap"
    played = {}
    with RecordAECEvidence(module.env(), path) as env:
        for game, seed in enumerate(SEEDS):
            played[game] = (seed, _play_aec(env, seed))
    ev = open_evidence(path)
    assert ev.run.layout["kind"] == "pettingzoo_aec"
    assert ev.run.layout["env_module"] == module.__name__
    assert ev.run.layout["env_id"] == REGISTRY_IDS[module]
    returns = _returns(path)
    for game, (seed, actions) in played.items():
        truth = _aec_truth(module.env, seed, actions)
        for agent, total in truth.items():
            assert returns[(game, agent)] == total
    # each agent's rows sum to its return; its rows are its live actions
    steps = ev.steps(columns=["episode", "reward", "action"])
    for record in ev.episodes().to_pylist():
        mine = steps.filter(steps.column("episode").to_numpy() == record["episode"])
        assert sum(mine.column("reward").to_pylist()) == record["return"]
        assert record["length"] == mine.num_rows
        assert record["outcome"] in ("success", "failure")  # every game ends by the rules
    result = replay([path])
    assert result.count("identical") == 2 * len(SEEDS), result.to_dict()
    assert check([path]).errors == 0


def test_tictactoe_loser_reward_arrives_on_the_winners_move(tmp_path: Path) -> None:
    path = tmp_path / "ttt.mcap"
    with RecordAECEvidence(tictactoe_v3.env(), path) as env:
        env.reset(seed=0)
        for move in [0, 3, 1, 4, 2]:  # player_1 takes the top row on its third move
            env.step(move)
        for _ in env.agent_iter():
            env.step(None)
    ev = open_evidence(path)
    rows = {r["agent"]: r for r in ev.episodes().to_pylist()}
    assert (rows["player_1"]["return"], rows["player_2"]["return"]) == (1.0, -1.0)
    loser = ev.episode(rows["player_2"]["episode"]).steps
    # player_2's last row: its move 4, the -1 that player_1's winning move gave it, terminated
    assert loser.column("action").to_pylist() == [3, 4]
    assert loser.column("reward").to_pylist() == [0.0, -1.0]
    assert loser.column("terminated").to_pylist() == [False, True]


class _Everyone(AECEnv):  # type: ignore[misc]
    """Three agents take turns; every step pays every agent ``step index`` (for the test only).

    ``last()``'s cumulative reward of an agent is the sum since it last acted, so a recorder
    that adds it up after every step double counts.
    """

    metadata = {"name": "everyone_v0"}

    def __init__(self) -> None:
        super().__init__()
        from gymnasium.spaces import Box, Discrete

        self.possible_agents = ["a", "b", "c"]
        self._obs = Box(0.0, 100.0, (1,), np.float32)
        self._act = Discrete(2)

    def observation_space(self, agent: str) -> Any:
        return self._obs

    def action_space(self, agent: str) -> Any:
        return self._act

    def observe(self, agent: str) -> Any:
        return np.array([self.t], dtype=np.float32)

    def reset(self, seed: int | None = None, options: Any = None) -> None:
        self.agents = list(self.possible_agents)
        self.t = 0
        self.rewards = dict.fromkeys(self.agents, 0.0)
        self._cumulative_rewards = dict.fromkeys(self.agents, 0.0)
        self.terminations = dict.fromkeys(self.agents, False)
        self.truncations = dict.fromkeys(self.agents, False)
        self.infos: dict[str, dict[str, Any]] = {a: {} for a in self.agents}
        self.agent_selection = "a"

    def step(self, action: Any) -> None:
        agent = self.agent_selection
        if self.terminations[agent] or self.truncations[agent]:
            self._was_dead_step(action)
            return
        self._cumulative_rewards[agent] = 0.0
        self.t += 1
        self.rewards = dict.fromkeys(self.agents, float(self.t))
        if self.t >= 7:
            self.truncations = dict.fromkeys(self.agents, True)
        self.agent_selection = self.agents[(self.agents.index(agent) + 1) % len(self.agents)]
        self._accumulate_rewards()


def test_aec_cumulative_reward_is_not_double_counted(tmp_path: Path) -> None:
    path = tmp_path / "everyone.mcap"
    truth: dict[str, float] = defaultdict(float)
    naive: dict[str, float] = defaultdict(float)
    with RecordAECEvidence(_Everyone(), path) as env:
        env.reset(seed=0)
        for _agent in env.agent_iter():
            _, _, term, trunc, _ = env.last()
            env.step(None if term or trunc else 1)
            for a, reward in env.rewards.items():
                truth[a] += reward
            for a in env.agents:  # a last()-after-every-step recorder, for every agent
                naive[a] += env._cumulative_rewards[a]
    returns = {r["agent"]: r["return"] for r in open_evidence(path).episodes().to_pylist()}
    assert returns == dict(truth) == {"a": 28.0, "b": 28.0, "c": 28.0}
    assert dict(naive) != dict(truth)  # the env tells the two apart
    assert open_evidence(path).episodes().column("truncated").to_pylist() == [True] * 3
    # the 7 steps are a's turns 1, 4, 7 and b's 2, 5 and c's 3, 6
    assert open_evidence(path).episodes().column("length").to_pylist() == [3, 2, 2]


@pytest.mark.filterwarnings("ignore:Observation numpy array is all zeros:UserWarning")
def test_aec_api_test_passes_on_the_wrapped_env(tmp_path: Path) -> None:
    with RecordAECEvidence(tictactoe_v3.env(), tmp_path / "api.mcap") as env:
        api_test(env, num_cycles=100)
    assert check([tmp_path / "api.mcap"]).errors == 0
    seeded = [r for r in replay([tmp_path / "api.mcap"]).episodes if r.status != "not_replayable"]
    assert seeded and all(r.status == "identical" for r in seeded)


class _Crashing(BaseWrapper):  # type: ignore[misc]
    """An AEC env whose ``crash_at``-th step of a game raises (after changing it, if ``late``)."""

    def __init__(self, env: Any, crash_at: int, late: bool = False) -> None:
        super().__init__(env)
        self.crash_at, self.late, self.n = crash_at, late, 0

    def reset(self, seed: int | None = None, options: Any = None) -> None:
        self.n = 0
        super().reset(seed=seed, options=options)

    def step(self, action: Any) -> None:
        self.n += 1
        if self.n == self.crash_at and not self.late:
            raise RuntimeError("engine crashed")
        super().step(action)
        if self.n == self.crash_at:
            raise RuntimeError("engine crashed late")


def _crashing_ttt(crash_at: int, late: bool = False) -> Any:
    return lambda: _Crashing(tictactoe_v3.env(), crash_at, late)


def _record_crash(path: Path, make: Any, message: str) -> None:
    """Game 0 (seed 0): moves 0, 3, 1, 4 — the 4th raises; game 1 (seed 1): one move."""
    with RecordAECEvidence(make(), path) as env:
        env.reset(seed=0)
        for move in [0, 3, 1]:
            env.step(move)
        with pytest.raises(RuntimeError, match=message):
            env.step(4)
        # valid before close, and the error game is over: nothing is added to it later
        assert [r["outcome"] for r in open_evidence(path).episodes().to_pylist()] == ["error"] * 2
        env.reset(seed=1)
        env.step(4)


class _TextRewards(BaseWrapper):  # type: ignore[type-arg]
    """Tic-tac-toe whose rewards are text (``"1"``): no numbers, as in a Gymnasium env."""

    @property
    def rewards(self) -> dict[str, Any]:
        return {agent: str(value) for agent, value in self.env.rewards.items()}

    @rewards.setter
    def rewards(self, value: Any) -> None:
        pass


def test_aec_text_rewards_are_nan_noted_and_replay_identically(tmp_path: Path) -> None:
    path = tmp_path / "text.mcap"

    def make() -> Any:
        return _TextRewards(tictactoe_v3.env())

    with RecordAECEvidence(make(), path) as env:
        env.reset(seed=0)
        for move in [0, 3, 1, 4, 2]:  # player_1 wins with its third move
            env.step(move)
    returns = [r["return"] for r in open_evidence(path).episodes().to_pylist()]
    assert len(returns) == 2 and all(math.isnan(r) for r in returns)
    assert {f.code for f in check([path]).findings} >= {"recorder_note:reward_not_numeric"}
    result = replay([path], env_factory=make)
    assert [r.status for r in result.episodes] == ["identical"] * 2, result.episodes


def test_an_aec_game_ended_before_its_dead_steps_replays_identically(tmp_path: Path) -> None:
    """A loop that stops at the game's end (no ``env.agent_iter()``) and resets or closes: the
    rows close then, not at the dead steps that replay would otherwise take."""
    path = tmp_path / "stop.mcap"
    with RecordAECEvidence(tictactoe_v3.env(), path) as env:
        for seed in range(2):
            env.reset(seed=seed)
            for move in [0, 3, 1, 4, 2]:  # player_1 wins with its third move
                env.step(move)
    result = replay([path], env_factory=tictactoe_v3.env)
    assert [r.status for r in result.episodes] == ["identical"] * 4, result.episodes
    # a game that replays otherwise still differs (its rewards, as text, are no numbers; a
    # factory's env, unverified: not_replayable, its difference kept)
    changed = replay([path], env_factory=lambda: _TextRewards(tictactoe_v3.env()))
    assert [r.status for r in changed.episodes] == ["not_replayable"] * 4
    assert {r.divergence.field for r in changed.episodes if r.divergence} == {"reward"}


def test_an_aec_step_that_raises_keeps_the_moves_that_completed(tmp_path: Path) -> None:
    path = tmp_path / "crash.mcap"
    make = _crashing_ttt(4)
    _record_crash(path, make, "^engine crashed$")
    ev = open_evidence(path)
    rows = ev.episodes().to_pylist()
    got = [(r["game"], r["agent"], r["outcome"], r["length"], r["error_during"]) for r in rows]
    assert got == [
        # player_1's moves 0 and 1 completed; player_2's 3 did, its 4 raised (no row, as a
        # Gymnasium step that raises)
        (0, "player_1", "error", 2, "step"),
        (0, "player_2", "error", 1, "step"),
        (1, "player_1", "incomplete", 1, None),
        (1, "player_2", "incomplete", 0, None),
    ]
    assert {r["error_message"] for r in rows[:2]} == {"engine crashed"}
    assert ev.episode(0).steps.column("action").to_pylist() == [0, 1]
    assert ev.episode(1).steps.column("action").to_pylist() == [3]
    # no row after an end (step_after_end): only the error itself, and notes (game 1 was
    # cut by close(); tic-tac-toe reports no reward terms)
    found = check([path]).findings
    assert sorted({(f.severity, f.code) for f in found}) == [
        ("error", "error_episode"),
        ("note", "incomplete_episode"),
        ("note", "missing_terms"),
    ]
    assert [f.episode for f in found if f.code == "error_episode"] == [0, 1]
    result = replay([path], env_factory=make)
    assert [(r.status, r.steps) for r in result.episodes] == [
        ("identical", 2),
        ("identical", 1),
        ("identical", 1),
    ], result.to_dict()
    assert result.unstarted == 1


def test_an_aec_step_that_changes_the_env_and_raises_is_not_replayed_past_it(
    tmp_path: Path,
) -> None:
    path = tmp_path / "late.mcap"
    make = _crashing_ttt(4, late=True)  # player_2's move 4 is played, then the step raises
    _record_crash(path, make, "^engine crashed late$")
    assert [r["length"] for r in open_evidence(path).episodes().to_pylist()] == [2, 1, 1, 0]
    first, *others = replay([path], env_factory=make).episodes
    # player_1's move 1 was closed with the board after the failed step (it holds the 4):
    # a replay, which does not repeat that step, cannot have it
    assert (first.status, first.steps) == ("not_replayable", 1)
    assert first.reason is not None
    assert first.reason.startswith(
        "game 0, after player_1's step 1 (the game's last recorded action): recorded: the env "
        "raised RuntimeError: engine crashed late here; replay: it stops at player_2's step 1, "
        "which raised: its action is not in the file, so its step 1, closed with the env's "
        "state when the env raised, cannot be compared (step 1: observation expected "
    )
    assert [r.status for r in others] == ["identical"] * 2


def _record_crash_after_win(path: Path, crash_at: int, flush_every_s: float = 1.0) -> None:
    """Tic-tac-toe, seed 0: player_1 wins with its third move (step 5); the dead steps follow,
    player_2's (step 6) then player_1's (step 7), and step ``crash_at`` raises."""
    make = _crashing_ttt(crash_at)
    with RecordAECEvidence(make(), path, flush_every_s=flush_every_s) as env:
        env.reset(seed=0)
        for move in [0, 3, 1, 4, 2]:
            env.step(move)
        for _ in range(crash_at - 6):
            env.step(None)  # player_2's dead step
        with pytest.raises(RuntimeError, match=r"^engine crashed$"):  # the loop still gets it
            env.step(None)


@pytest.mark.parametrize(
    ("crash_at", "whose"),
    [
        (6, "player_2"),  # player_1's winning move is still an open row: it closes after it
        (7, "player_1"),  # every row had closed (player_1's at its dead turn)
    ],
)
@pytest.mark.parametrize("flush_every_s", [1.0, 1e-9])  # 1e-9: each row is flushed at once
def test_an_aec_dead_step_that_raises_after_every_agent_ended_is_noted(
    tmp_path: Path, crash_at: int, whose: str, flush_every_s: float
) -> None:
    path = tmp_path / "ttt.mcap"
    _record_crash_after_win(path, crash_at, flush_every_s)
    ev = open_evidence(path)
    rows = ev.episodes().to_pylist()
    # both agent-episodes had ended by their flags when the env raised: no episode was in
    # progress, so none ends `error` and their outcomes stand...
    assert [
        (r["agent"], r["outcome"], r["terminated"], r["length"], r["return"], r["error_type"])
        for r in rows
    ] == [
        ("player_1", "failure", True, 3, 1.0, None),  # tictactoe gives no success key
        ("player_2", "failure", True, 2, -1.0, None),
    ]
    # ...and the last row the failing step() closed says what raised, where
    steps = ev.steps(columns=["episode", "step", "notes"]).to_pylist()
    noted = [(s["episode"], s["step"], json.loads(s["notes"])) for s in steps if s["notes"]]
    assert noted == [
        (
            0,
            2,
            [
                "env_raised: RuntimeError: engine crashed (during step: "
                f"{whose}'s dead step, after every agent-episode of game 0 had ended)"
            ],
        )
    ]
    assert [r["notes"] for r in rows] == [1, 0]
    found = check([path])
    assert [
        (f.severity, f.episode, f.step, "RuntimeError: engine crashed" in f.message)
        for f in found.findings
        if f.code == "recorder_note:env_raised"
    ] == [("error", 0, 2, True)]  # the env raised: an error, as an error episode is
    assert not found.ok


def test_a_step_that_raises_again_in_a_game_that_raised_warns_that_it_is_not_noted(
    tmp_path: Path,
) -> None:
    path = tmp_path / "leaving.mcap"
    with RecordAECEvidence(_Leaving(broken_dead=True), path) as env:
        env.reset(seed=0)
        for _ in range(4):
            env.step(1)  # a is terminated by its second action: its dead step comes next
        with pytest.raises(RuntimeError, match=r"^dead step broke$"):
            env.step(None)  # b and c end error
        # every agent-episode has ended and this step closes no row: nowhere to note it
        with (
            pytest.warns(RuntimeWarning, match=r"closed no row.*env_raised: RuntimeError: dead"),
            pytest.raises(RuntimeError, match=r"^dead step broke$"),
        ):
            env.step(None)
    outcomes = [r["outcome"] for r in open_evidence(path).episodes().to_pylist()]
    assert outcomes == ["failure", "error", "error"]


@pytest.mark.parametrize("crash_at", [6, 7])
def test_replay_explains_a_dead_step_that_raised_after_every_agent_ended(
    tmp_path: Path, crash_at: int
) -> None:
    path = tmp_path / "ttt.mcap"
    _record_crash_after_win(path, crash_at)
    # a replay whose dead step raises there too has the recorded game's state
    assert (
        _statuses(replay([path], env_factory=_crashing_ttt(crash_at))) == [("identical", None)] * 2
    )
    first, second = replay([path]).episodes
    assert (second.status, second.steps) == ("identical", 2)
    if crash_at == 7:  # every row closed before the dead step that raised
        assert (first.status, first.steps) == ("identical", 3)
        return
    # player_1's winning row was closed with the env's state when player_2's dead step
    # raised; the replay performs that dead step (player_2 leaves) and closes it after it
    assert (first.status, first.steps) == ("not_replayable", 2)
    assert (first.reason or "").startswith(
        "game 0, after player_1's step 2 (the game's last recorded action): recorded: the env "
        "raised RuntimeError: engine crashed here; replay: it did not (it performed player_2's "
        "dead step, player_1's dead step), so its step 2, closed with the env's state when the "
        "env raised, cannot be compared (step 2: observation expected "
    ), first.reason


class _Leaving(_Everyone):
    """As :class:`_Everyone`, but ``a`` is terminated by its second action (at step 4) while
    ``b`` and ``c`` play on; its dead step comes next (PettingZoo's ``_deads_step_first``).
    Every agent observes the step index and how many agents are in the game. ``reset()``
    raises while ``broken_reset`` is set, a dead step while ``broken_dead`` is.
    """

    metadata = {"name": "leaving_v0"}

    def __init__(self, broken_dead: bool = False, broken_reset: bool = False) -> None:
        super().__init__()
        from gymnasium.spaces import Box

        self._obs = Box(0.0, 100.0, (2,), np.float32)
        self.broken_dead, self.broken_reset = broken_dead, broken_reset

    def observe(self, agent: str) -> Any:
        return np.array([self.t, len(self.agents)], dtype=np.float32)

    def reset(self, seed: int | None = None, options: Any = None) -> None:
        if self.broken_reset:
            raise RuntimeError("no board")
        super().reset(seed=seed, options=options)
        self._skip_agent_selection = None

    def step(self, action: Any) -> None:
        agent = self.agent_selection
        if self.terminations[agent] or self.truncations[agent]:
            if self.broken_dead:
                raise RuntimeError("dead step broke")
            self._was_dead_step(action)
            return
        super().step(action)
        if self.t == 4:
            self.terminations["a"] = True
            self._deads_step_first()


def _play_leaving(env: Any, seed: int) -> None:
    env.reset(seed=seed)
    for _agent in env.agent_iter():
        _, _, term, trunc, _ = env.last()
        env.step(None if term or trunc else 1)


def _statuses(result: Any) -> list[tuple[str, str | None]]:
    return [
        (r.status, None if r.divergence is None else r.divergence.describe())
        for r in result.episodes
    ]


def test_an_aec_dead_step_that_raised_only_when_recorded_is_not_called_diverged(
    tmp_path: Path,
) -> None:
    path = tmp_path / "leaving.mcap"
    with RecordAECEvidence(_Leaving(), path) as env:
        _play_leaving(env, 0)
        env.unwrapped.broken_dead = True
        with pytest.raises(RuntimeError, match=r"^dead step broke$"):
            _play_leaving(env, 1)  # a's dead step (after its second action) raises
    rows = open_evidence(path).episodes().to_pylist()
    assert [(r["game"], r["agent"], r["outcome"], r["length"]) for r in rows[3:]] == [
        (1, "a", "failure", 2),  # its last row closed at its (dead) turn, before the raise
        (1, "b", "error", 1),  # b's and c's open rows closed with the env's state then
        (1, "c", "error", 1),
    ]
    # their error episodes say the env raised: no row is noted env_raised
    notes = open_evidence(path).steps().column("notes").to_pylist()
    assert not [n for n in notes if n and "env_raised" in n]
    # the replay performs a's dead step itself: it does not raise, a leaves, and b's turn
    # comes, a state the recording never had; b's row was called diverged on its observation
    result = replay([path], env_factory=_Leaving)
    assert [r.status for r in result.episodes] == ["identical"] * 4 + ["not_replayable"] * 2
    for replayed, agent in zip(result.episodes[4:], "bc", strict=True):
        assert replayed.steps == 0
        assert re.fullmatch(
            r"game 1, after a's step 1 \(the game's last recorded action\): recorded: the env "
            r"raised RuntimeError: dead step broke here; replay: it did not \(it performed a's "
            r"dead step\), so its step 0, closed with the env's state when the env raised, "
            r"cannot be compared \(step 0: observation expected \[4\.0, 3\.0\], got "
            r"\[4\.0, 2\.0\] \(max abs diff 1\)\)",
            replayed.reason or "",
        ), (agent, replayed.reason)
    # a replay whose dead step raises there too has the recorded game's state
    again = replay([path], env_factory=lambda: _Leaving(broken_dead=True)).episodes
    assert [r.status for r in again[3:]] == ["identical"] * 3


def test_an_aec_replay_that_raises_where_the_recording_did_not_diverges_there(
    tmp_path: Path,
) -> None:
    # game 0 of this file raised on its 4th step, game 1 did not
    path = tmp_path / "crash.mcap"
    _record_crash(path, _crashing_ttt(4), "^engine crashed$")
    # the replay raises on the 2nd step (player_2's first move), which the recording completed
    early = replay([path], env_factory=_crashing_ttt(2))
    assert _statuses(early) == [
        (
            "not_replayable",
            "step 0: step expected a step, got RuntimeError: engine crashed "
            "(raised in player_2's step 0)",
        ),
        ("not_replayable", "step 0: step expected a step, got RuntimeError: engine crashed"),
        ("identical", None),
    ]
    # a dead step that raises only on replay: b and c never completed a row
    leaving = tmp_path / "leaving.mcap"
    with RecordAECEvidence(_Leaving(), leaving) as env:
        _play_leaving(env, 0)
    dead = replay([leaving], env_factory=lambda: _Leaving(broken_dead=True))
    assert _statuses(dead) == [
        ("identical", None),
        (
            "not_replayable",
            "step 0: step expected a step, got RuntimeError: dead step broke "
            "(raised in a's dead step)",
        ),
        (
            "not_replayable",
            "step 0: step expected a step, got RuntimeError: dead step broke "
            "(raised in a's dead step)",
        ),
    ]
    # a reset that raises only on replay: every agent-episode, rows or not, as a single env
    reset = replay([leaving], env_factory=lambda: _Leaving(broken_reset=True))
    assert (
        _statuses(reset)
        == [("not_replayable", "reset: reset expected a reset, got RuntimeError: no board")] * 3
    )


class _ResetFails(BaseParallelWrapper):  # type: ignore[misc]
    """A Parallel env whose ``reset()`` raises while ``broken_reset`` is set."""

    broken_reset = False

    def reset(self, seed: int | None = None, options: Any = None) -> Any:
        if self.broken_reset:
            raise RuntimeError("no board")
        return super().reset(seed=seed, options=options)


def _play_rps(env: Any, seed: int) -> None:
    env.reset(seed=seed)
    while env.agents:
        env.step(dict.fromkeys(env.agents, 1))


@pytest.mark.parametrize("api", ["aec", "parallel"])
def test_a_game_whose_reset_raised_is_not_replayable(tmp_path: Path, api: str) -> None:
    """As a single env's episode whose reset raised, though the replay's reset does not."""
    path = tmp_path / "reset.mcap"
    if api == "aec":
        recorder: Any = RecordAECEvidence(_Leaving(), path)
        play, broken, make = _play_leaving, recorder.unwrapped, _Leaving
    else:
        recorder = RecordParallelEvidence(_ResetFails(rps_v2.parallel_env(max_cycles=3)), path)
        play, broken, make = _play_rps, recorder.env, lambda: rps_v2.parallel_env(max_cycles=3)
    with recorder as env:
        play(env, 0)
        broken.broken_reset = True
        with pytest.raises(RuntimeError, match=r"^no board$"):
            env.reset(seed=1)  # game 1: no reset row, no step
        broken.broken_reset = False
        play(env, 2)
    rows = open_evidence(path).episodes().to_pylist()
    agents = len(rows) // 3
    assert [(r["game"], r["error_during"]) for r in rows] == [(0, None)] * agents + [
        (1, "reset")
    ] * agents + [(2, None)] * agents
    assert {r["outcome"] for r in rows if r["game"] == 1} == {"error"}
    result = replay([path], env_factory=make)
    assert [(r.status, r.reason) for r in result.episodes] == [("identical", None)] * agents + [
        ("not_replayable", "its reset raised (an error episode): there is no reset to compare")
    ] * agents + [("identical", None)] * agents


def _torn_copy(src: Path, dst: Path) -> Path:
    shutil.copyfile(src, dst)  # what a SIGKILL right after flush() leaves on disk
    return dst


def test_a_torn_aec_game_replays_what_it_can_and_never_diverges(tmp_path: Path) -> None:
    path, torn, recovered = tmp_path / "c4.mcap", tmp_path / "torn.mcap", tmp_path / "rec.mcap"
    with RecordAECEvidence(connect_four_v3.env(), path) as env:
        env.reset(seed=0)
        for move in [3, 3, 4]:
            env.step(move)
        env.flush()
        _torn_copy(path, torn)
    # player_0's move 3 closed at its second turn (after player_1's move 3); player_1's 3 and
    # player_0's 4 were still open rows: their actions are not in the file
    rows = open_evidence(torn).episodes().to_pylist()
    assert [(r["agent"], r["outcome"], r["length"], r["ended"]) for r in rows] == [
        ("player_0", "incomplete", 1, False),
        ("player_1", "incomplete", 0, False),
    ]
    assert check([torn]).errors == 0
    assert recover(torn, recovered).cut_off_episodes == (0, 1)
    for file in (torn, recovered):
        first, second = replay([file]).episodes
        assert (first.status, first.steps) == ("not_replayable", 0)
        assert first.reason == (
            "cut off by the torn file: its step 0 was recorded after player_1's step 0, whose "
            "action is not in the file, so the replay cannot reach it (what comes before it "
            "replays identical)"
        )
        assert (second.status, second.steps) == ("identical", 0)  # its reset row
    assert replay([path]).count("identical") == 2  # the finished file: cut by close()


def test_a_torn_tictactoe_reset_row_after_a_lost_move_is_not_replayable(tmp_path: Path) -> None:
    path, torn = tmp_path / "ttt.mcap", tmp_path / "torn.mcap"
    with RecordAECEvidence(tictactoe_v3.env(), path) as env:
        env.reset(seed=0)
        for move in [0, 3]:
            env.step(move)
        env.flush()
        _torn_copy(path, torn)
    # no step rows; player_2's reset row is the board after player_1's move 0 (an open row)
    assert [r["length"] for r in open_evidence(torn).episodes().to_pylist()] == [0, 0]
    first, second = replay([torn]).episodes
    assert (first.status, second.status) == ("identical", "not_replayable")
    assert second.reason == (
        "cut off by the torn file: its reset row was recorded after player_1's step 0, whose "
        "action is not in the file, so the replay cannot reach it (what comes before it "
        "replays identical)"
    )


@pytest.mark.parametrize("module", [tictactoe_v3, connect_four_v3])
def test_aec_files_torn_after_any_turn_never_diverge(tmp_path: Path, module: Any) -> None:
    path, torn = tmp_path / "rec.mcap", tmp_path / "torn.mcap"
    actions = _play_aec(module.env(), 2)  # a whole game, its dead steps as None
    cut_off = 0
    for turns in range(len(actions) + 1):
        with RecordAECEvidence(module.env(), path, overwrite=True) as env:
            _play_aec(env, 1)  # a finished game, then one torn after `turns` turns
            env.reset(seed=2)
            for action in actions[:turns]:
                env.step(action)
            env.flush()
            _torn_copy(path, torn)
        result = replay([torn])
        statuses = [r.status for r in result.episodes]
        assert "diverged" not in statuses, (turns, result.to_dict())
        assert statuses[:2] == ["identical", "identical"]  # game 0
        # at most one agent's row (or reset row) was recorded after a move the file lost
        assert statuses.count("not_replayable") <= 1, (turns, result.to_dict())
        cut_off += statuses.count("not_replayable")
        assert check([torn]).errors == 0
    assert statuses == ["identical"] * 4  # the whole game, dead steps and all
    assert cut_off > 0


# ------------------------------------------------------------------------------- Parallel


def _rps_step(t: int, agents: list[Any]) -> dict[Any, int]:
    return {agent: (t + i) % 3 for i, agent in enumerate(agents)}


def test_a_parallel_step_is_never_split_by_a_flush_due_amid_its_agents_rows(
    tmp_path: Path,
) -> None:
    path, torn = tmp_path / "rps.mcap", tmp_path / "torn.mcap"
    kwargs = {"max_cycles": 50}
    with RecordParallelEvidence(
        rps_v2.parallel_env(**kwargs), path, env_kwargs=kwargs, block_steps=8, flush_every_s=3600
    ) as env:
        head = path.stat().st_size
        env.reset(seed=3)
        for t in range(10):  # the 8th step fills player_0's block before player_1's row
            env.step(_rps_step(t, env.agents))
        deadline = time.monotonic() + 30
        while path.stat().st_size == head and time.monotonic() < deadline:
            time.sleep(0.01)  # (the flush's chunk is written by the writer thread)
        _torn_copy(path, torn)  # what a SIGKILL now leaves on disk
    rows = open_evidence(torn).episodes().to_pylist()
    assert [(r["agent"], r["length"], r["ended"]) for r in rows] == [
        ("player_0", 8, False),
        ("player_1", 8, False),
    ]
    assert replay([torn]).count("identical") == 2


class _FlushAmidStep(BaseParallelWrapper):  # type: ignore[misc]
    """rps whose step ``flush_at`` has its recorder's file flushed after player_0's row.

    The recorder reads each agent's share of a step's result as it records that agent's row
    (``obs.get(agent)``): the file's flush then writes the rows recorded so far, as recorders
    that flushed when a block filled amid a step's rows did (files they wrote are out there).
    """

    recorder: Any = None
    flush_at = -1

    def __init__(self) -> None:
        super().__init__(rps_v2.parallel_env(max_cycles=50))
        self.steps = 0

    def step(self, actions: Any) -> Any:
        obs, *rest = super().step(actions)
        self.steps += 1
        if self.steps == self.flush_at:
            obs = _FlushingObs(obs, self.recorder, self.possible_agents[1])
        return (obs, *rest)


class _FlushingObs(dict):  # type: ignore[type-arg]
    def __init__(self, obs: Any, recorder: Any, agent: Any) -> None:
        super().__init__(obs)
        self.recorder, self.agent = recorder, agent

    def get(self, key: Any, default: Any = None) -> Any:
        if key == self.agent:
            self.recorder._file.flush()
        return super().get(key, default)


def test_a_parallel_game_torn_amid_a_step_is_cut_off_not_diverged(tmp_path: Path) -> None:
    path, torn, recovered = tmp_path / "rps.mcap", tmp_path / "torn.mcap", tmp_path / "rec.mcap"
    inner = _FlushAmidStep()
    inner.flush_at = 8
    with RecordParallelEvidence(inner, path, env_kwargs={"max_cycles": 50}) as env:
        inner.recorder = env
        env.reset(seed=3)
        for t in range(8):
            env.step(_rps_step(t, env.agents))
        _torn_copy(path, torn)
    rows = open_evidence(torn).episodes().to_pylist()
    assert [(r["agent"], r["length"], r["ended"]) for r in rows] == [
        ("player_0", 8, False),
        ("player_1", 7, False),
    ]
    assert recover(torn, recovered).cut_off_episodes == (0, 1)
    for file in (torn, recovered):
        first, second = replay([file]).episodes
        assert (first.status, first.steps) == ("not_replayable", 7)
        assert first.reason == (
            "cut off by the torn file: its step 7 was recorded in the same step() as "
            "player_1's step 7, whose action is not in the file, so the replay cannot reach it "
            "(what comes before it replays identical)"
        )
        assert (second.status, second.steps) == ("identical", 7)


def _play_parallel(env: Any, seed: int) -> list[dict[str, Any]]:
    env.reset(seed=seed)
    for agent in env.possible_agents:
        env.action_space(agent).seed(seed)
    joint = []
    while env.agents:
        actions = {a: env.action_space(a).sample() for a in env.agents}
        joint.append(actions)
        env.step(actions)
    return joint


def test_kaz_agents_leave_mid_game_returns_and_replay(tmp_path: Path) -> None:
    path = tmp_path / "kaz.mcap"
    played = {}
    with RecordParallelEvidence(kaz.parallel_env(**KAZ_KWARGS), path, env_kwargs=KAZ_KWARGS) as env:
        for game, seed in enumerate(KAZ_SEEDS):
            played[game] = (seed, _play_parallel(env, seed))
    returns = _returns(path)
    left_early = 0
    for game, (seed, joint) in played.items():
        twin = kaz.parallel_env(**KAZ_KWARGS)
        twin.reset(seed=seed)
        truth: dict[str, float] = defaultdict(float)
        lengths: dict[str, int] = defaultdict(int)
        for actions in joint:
            _, rewards, _, _, _ = twin.step(actions)
            for agent in actions:
                truth[agent] += float(rewards[agent])
                lengths[agent] += 1
        assert {a: returns[(game, a)] for a in truth} == dict(truth)
        left_early += sum(n < len(joint) for n in lengths.values())
    assert left_early > 0  # agents died and left before their game ended
    assert open_evidence(path).run.layout["env_id"] == REGISTRY_IDS[kaz]
    rows = open_evidence(path).episodes().to_pylist()
    assert {r["outcome"] for r in rows} <= {"failure", "truncated"}
    assert all(r["game"] in (0, 1) for r in rows)
    result = replay([path])
    assert result.count("identical") == len(rows), result.to_dict()
    assert check([path]).errors == 0


def test_parallel_api_test_passes_on_the_wrapped_envs(tmp_path: Path) -> None:
    with RecordParallelEvidence(
        kaz.parallel_env(max_cycles=40), tmp_path / "kaz.mcap", env_kwargs={"max_cycles": 40}
    ) as env:
        parallel_api_test(env, num_cycles=50)
    with RecordParallelEvidence(rps_v2.parallel_env(), tmp_path / "rps.mcap") as env:
        parallel_api_test(env, num_cycles=20)
    assert check([tmp_path / "kaz.mcap", tmp_path / "rps.mcap"]).errors == 0


class _PaysAtStep2(BaseParallelWrapper):  # type: ignore[misc]
    """rps_v2 (max_cycles=5) whose third step pays every agent 1 more."""

    def __init__(self) -> None:
        super().__init__(rps_v2.parallel_env(max_cycles=5))
        self.steps = 0

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        self.steps = 0
        return self.env.reset(seed=seed, options=options)

    def step(self, actions: dict[str, Any]) -> Any:
        self.steps += 1
        obs, rewards, term, trunc, infos = self.env.step(actions)
        if self.steps == 3:
            rewards = {agent: reward + 1 for agent, reward in rewards.items()}
        return obs, rewards, term, trunc, infos


def test_replay_reports_where_a_game_diverged(tmp_path: Path) -> None:
    path = tmp_path / "rps.mcap"
    with RecordParallelEvidence(
        rps_v2.parallel_env(max_cycles=5), path, env_kwargs={"max_cycles": 5}
    ) as env:
        for seed in (3, 4):
            env.reset(seed=seed)
            while env.agents:
                env.step({a: 2 for a in env.agents})
    result = replay([path], env_factory=_PaysAtStep2)
    first = result.episodes[0]
    assert first.status == "not_replayable" and first.divergence is not None
    assert (first.divergence.step, first.divergence.field) == (2, "reward")
    assert [e.restored for e in result.episodes] == [
        "seed 3; first game in this env",
        "seed 3; first game in this env",
        "seed 4; this env after 1 earlier game",
        "seed 4; this env after 1 earlier game",
    ]
    assert replay([path]).count("identical") == 4  # built from the recorded kwargs


def _with_layout(src: Path, dst: Path, **changes: Any) -> Path:
    """Copy an evidence file with some of its layout keys changed (as a hand edit would)."""

    def run(meta: dict[str, str]) -> dict[str, str]:
        return {**meta, "layout": json.dumps({**json.loads(meta["layout"]), **changes})}

    return rewrite(src, dst, run=run)


def test_replay_builds_only_pettingzoo_modules_without_trust(tmp_path: Path) -> None:
    recorded = tmp_path / "recorded.mcap"
    with RecordAECEvidence(tictactoe_v3.env(), recorded, env_module="os") as env:
        _play_aec(env, 0)
    path = _with_layout(recorded, tmp_path / "ttt.mcap", env_id=None)  # as before PettingZoo 1.27
    (r1, _r2) = replay([path]).episodes
    assert r1.status == "not_replayable"
    assert r1.reason is not None and "not one of PettingZoo's own" in r1.reason
    assert replay([path], env_factory=tictactoe_v3.env).count("identical") == 2
    wrong = replay([path], env_factory=rps_v2.parallel_env).episodes  # a ParallelEnv
    assert [r.status for r in wrong] == ["not_replayable"] * 2
    assert wrong[0].reason is not None and "not a PettingZoo AECEnv" in wrong[0].reason
    assert env_module_of(connect_four_v3.env()) == "pettingzoo.classic.connect_four_v3"


def test_replay_makes_a_registered_id_without_importing_the_deprecated_module(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ttt, rps = tmp_path / "ttt.mcap", tmp_path / "rps.mcap"
    with RecordAECEvidence(pettingzoo.make("aec", "classic/tictactoe-v3"), ttt) as env:
        _play_aec(env, 0)
    made = pettingzoo.make("parallel", "classic/rps-v2", max_cycles=4)
    with RecordParallelEvidence(made, rps, env_kwargs={"max_cycles": 4}) as penv:
        _play_parallel(penv, 1)
    assert open_evidence(ttt).run.layout["env_id"] == "classic/tictactoe-v3"
    assert open_evidence(rps).run.layout["env_id"] == "classic/rps-v2"
    for module in ("pettingzoo.classic.tictactoe_v3", "pettingzoo.classic.rps_v2"):
        monkeypatch.delitem(sys.modules, module, raising=False)  # replay by module imports it
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        assert replay([ttt, rps]).count("identical") == 4
    assert "pettingzoo.classic.tictactoe_v3" not in sys.modules
    assert "pettingzoo.classic.rps_v2" not in sys.modules


PZ_CANARY = """
from pathlib import Path
Path(__file__).with_name("IMPORTED").touch()
def env(**kwargs):
    raise RuntimeError("canary called")
"""


def test_an_unregistered_id_imports_nothing_and_is_not_replayable(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "ea_pz_canary.py").write_text(PZ_CANARY)
    monkeypatch.syspath_prepend(str(tmp_path))
    recorded = tmp_path / "recorded.mcap"
    with RecordAECEvidence(tictactoe_v3.env(), recorded) as env:
        _play_aec(env, 0)
    cases = {
        "evil/canary-v1": "ea_pz_canary",  # an id nobody registered, a module outside PettingZoo
        "classic/tictactoe-v99": None,  # a version this PettingZoo does not have, no module
    }
    for env_id, module in cases.items():
        path = _with_layout(
            recorded, tmp_path / f"{len(env_id)}.mcap", env_id=env_id, env_module=module
        )
        results = replay([path]).episodes
        assert [r.status for r in results] == ["not_replayable"] * 2
        reason = results[0].reason or ""
        assert f"env id {env_id!r} is not registered in this process's PettingZoo AEC" in reason
        if module is None:
            assert "the file names no PettingZoo env module; pass --env-factory" in reason
        else:
            assert "'ea_pz_canary' is not one of PettingZoo's own" in reason
        code = CliRunner().invoke(app, ["replay", str(path), "-f", "json"]).exit_code
        assert code == 1  # nothing verified
        allowed = ["replay", str(path), "-f", "json", "--allow-unverified"]
        assert CliRunner().invoke(app, allowed).exit_code == 0  # not replayable is no finding
    assert "ea_pz_canary" not in sys.modules and not (tmp_path / "IMPORTED").exists()
    assert not pettingzoo.aec_registry.keys() & cases.keys()  # nothing was registered either


def test_explicit_env_id_is_resolved_and_checked(tmp_path: Path) -> None:
    path = tmp_path / "ttt.mcap"
    with RecordAECEvidence(tictactoe_v3.env(), path, env_id="classic/tictactoe") as env:
        _play_aec(env, 0)
    assert open_evidence(path).run.layout["env_id"] == "classic/tictactoe-v3"  # the version
    with pytest.raises(ConfigurationError, match="'classic/nope-v1' is not registered in Petti"):
        RecordAECEvidence(tictactoe_v3.env(), tmp_path / "x.mcap", env_id="classic/nope-v1")
    with pytest.raises(ConfigurationError, match="not registered in PettingZoo's parallel regi"):
        # tictactoe has no parallel API
        RecordParallelEvidence(
            rps_v2.parallel_env(), tmp_path / "x.mcap", env_id="classic/tictactoe-v3"
        )
    assert not (tmp_path / "x.mcap").exists()
    assert env_id_of(tictactoe_v3.env(), "pettingzoo_parallel") is None
    assert env_id_of(_Everyone(), "pettingzoo_aec") is None  # not registered


def test_an_id_the_user_registered_is_recorded_and_replayed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    spec = pettingzoo.EnvSpec(id="tests/everyone-v0", entry_point=_Everyone)
    monkeypatch.setitem(pettingzoo.aec_registry, spec.id, spec)
    path = tmp_path / "everyone.mcap"
    with RecordAECEvidence(_Everyone(), path) as env:
        env.reset(seed=0)
        for _agent in env.agent_iter():
            _, _, term, trunc, _ = env.last()
            env.step(None if term or trunc else 1)
    layout = open_evidence(path).run.layout
    assert (layout["env_id"], layout["env_module"], layout["notes"][1:]) == (
        "tests/everyone-v0",
        None,
        [],  # no "replay needs --env-factory": the id suffices
    )
    assert replay([path]).count("identical") == 3
    monkeypatch.delitem(pettingzoo.aec_registry, spec.id)  # a process that did not register it
    (first, *_) = replay([path]).episodes
    assert first.status == "not_replayable"
    assert "'tests/everyone-v0' is not registered" in (first.reason or "")


def test_pettingzoo_without_a_registry_records_and_replays_by_module(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    for name in ("aec_registry", "parallel_registry", "spec", "make"):  # as PettingZoo < 1.27
        monkeypatch.delattr(pettingzoo, name)
    path = tmp_path / "ttt.mcap"
    with RecordAECEvidence(tictactoe_v3.env(), path) as env:
        _play_aec(env, 0)
    layout = open_evidence(path).run.layout
    assert (layout["env_id"], layout["env_module"]) == (None, "pettingzoo.classic.tictactoe_v3")
    assert replay([path]).count("identical") == 2
    with pytest.raises(ConfigurationError, match=r"has no env registry \(PettingZoo 1.27\+\)"):
        RecordAECEvidence(tictactoe_v3.env(), tmp_path / "x.mcap", env_id="classic/tictactoe-v3")


class _TwoSpaces(_Everyone):
    def action_space(self, agent: str) -> Any:
        from gymnasium.spaces import Discrete

        return Discrete(3) if agent == "b" else self._act


def test_different_agent_spaces_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigurationError, match="different spaces are not supported yet"):
        RecordAECEvidence(_TwoSpaces(), tmp_path / "x.mcap")
    assert not (tmp_path / "x.mcap").exists()


# ------------------------------------------------------------------------------- report, CLI


def test_game_outcome_rule() -> None:
    assert game_outcome(["success", "success"]) == "success"
    assert game_outcome(["success", "truncated"]) == "truncated"
    assert game_outcome(["truncated", "failure", "success"]) == "failure"
    assert game_outcome(["failure", "incomplete"]) == "incomplete"
    assert game_outcome(["incomplete", "error"]) == "error"


def test_cli_report_by_agent_games_check_replay(tmp_path: Path) -> None:
    path = tmp_path / "kaz.mcap"
    with RecordParallelEvidence(kaz.parallel_env(**KAZ_KWARGS), path, env_kwargs=KAZ_KWARGS) as env:
        for seed in SEEDS[:2]:
            _play_parallel(env, seed)
    runner = CliRunner()
    by_agent = runner.invoke(app, ["report", str(path), "--by", "agent", "-f", "json"])
    assert by_agent.exit_code == 0, by_agent.output
    data = json.loads(by_agent.output)
    assert [g["key"] for g in data["groups"]] == ["archer_0", "archer_1", "knight_0", "knight_1"]
    assert all(g["episodes"] == 2 for g in data["groups"]) and data["unit"] == "episode"
    games = runner.invoke(app, ["report", str(path), "--games", "-f", "json"])
    assert games.exit_code == 0, games.output
    game_data = json.loads(games.output)
    assert game_data["unit"] == "game" and game_data["groups"][0]["episodes"] == 2
    refused = runner.invoke(app, ["report", str(path), "--games", "--by", "agent"])
    assert refused.exit_code == 2
    replayed = runner.invoke(app, ["replay", str(path), "-f", "json"])
    assert replayed.exit_code == 0, replayed.output
    assert json.loads(replayed.output)["summary"]["identical"] == 8
    checked = runner.invoke(app, ["check", str(path), "-f", "json"])
    assert checked.exit_code in (0, 1)  # warnings (unlabeled failures) are findings
    assert json.loads(checked.output)["counts"]["error"] == 0
    assert report([path], by="agent").groups[0].episodes == 2
    (by_index,) = report([path], by="env_index", games=True).groups
    assert (by_index.key, by_index.episodes) == ("0", 2)
