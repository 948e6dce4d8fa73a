"""PettingZoo replay (replay/pettingzoo.py) given hostile files and misbehaving envs.

The usual games are replayed in tests/record/test_pettingzoo.py; here a file's hand-edited
reset records and notes, and an env whose returned values raise when read.
"""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from pettingzoo.utils.wrappers import BaseParallelWrapper, MultiEpisodeEnv
from typer.testing import CliRunner

from episode_audit import (
    RecordAECEvidence,
    RecordParallelEvidence,
    check,
    open_evidence,
    replay,
)
from episode_audit.cli import app
from episode_audit.errors import ConfigurationError
from episode_audit.format import names as fmt
from tests.replay.test_misbehaving_env import UnprintableError, Unreadable
from tests.support.hostile import replace_column, rewrite

with warnings.catch_warnings():  # PettingZoo 1.27 deprecates the env modules (for make())
    warnings.simplefilter("ignore", DeprecationWarning)
    from pettingzoo.butterfly import pistonball_v6
    from pettingzoo.classic import go_v5, rps_v2, tictactoe_v3

DEEP = "[" * 100_000


def _rps(path: Path, games: int = 2) -> Path:
    with RecordParallelEvidence(
        rps_v2.parallel_env(max_cycles=3), path, env_kwargs={"max_cycles": 3}
    ) as env:
        for seed in range(games):
            env.reset(seed=seed)
            while env.agents:
                env.step(dict.fromkeys(env.agents, 1))
    return path


@pytest.fixture(scope="module")
def rps(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _rps(tmp_path_factory.mktemp("rps") / "rps.mcap")


def test_deeply_nested_reset_records_are_not_replayable_not_a_recursion_error(
    rps: Path, tmp_path: Path
) -> None:
    """Game 0's options and game 1's RNG state (its seed removed) are nested too deeply."""

    def episodes(batch: pa.RecordBatch) -> pa.RecordBatch:
        games = batch.column("game").to_pylist()
        batch = replace_column(batch, "options", [DEEP if g == 0 else None for g in games])
        batch = replace_column(batch, "seed", [0 if g == 0 else None for g in games])
        return replace_column(batch, "rng_state", [None if g == 0 else DEEP for g in games])

    evil = rewrite(rps, tmp_path / "deep.mcap", episodes=episodes)
    result = replay([evil])
    why = "its game's reset record: {} is nested too deeply to be JSON episode-audit wrote"
    assert [(e.status, e.reason) for e in result.episodes] == [
        ("not_replayable", why.format("options")),
        ("not_replayable", why.format("options")),
        ("not_replayable", why.format("rng_state")),
        ("not_replayable", why.format("rng_state")),
    ]


def test_deeply_nested_notes_are_read_as_no_notes(rps: Path, tmp_path: Path) -> None:
    """(Replay reads a game's notes for the error its step raised when recorded.)"""

    def steps(batch: pa.RecordBatch) -> pa.RecordBatch:
        return replace_column(batch, fmt.COL_NOTES, [DEEP] * batch.num_rows)

    evil = rewrite(rps, tmp_path / "notes.mcap", steps=steps)
    assert replay([evil]).count("identical") == 4


class _Spoiled(BaseParallelWrapper):  # type: ignore[misc]
    """rps whose second step returns an unreadable value for one agent (or raises)."""

    def __init__(self, field: str) -> None:
        super().__init__(rps_v2.parallel_env(max_cycles=3))
        self.field = field
        self.steps = 0

    def step(self, actions: dict[str, Any]) -> Any:
        self.steps += 1
        if self.steps == 2 and self.field == "raise":
            raise UnprintableError
        obs, rewards, term, trunc, infos = self.env.step(actions)
        if self.steps == 2:
            first = self.agents[0]
            if self.field == "observation":
                obs = {**obs, first: Unreadable()}
            if self.field == "reward":
                rewards = {**rewards, first: Unreadable()}
        return obs, rewards, term, trunc, infos


@pytest.mark.parametrize(
    ("field", "described"),
    [
        ("observation", "step 1: observation expected 1, got <a Unreadable whose repr() raised"),
        ("reward", "step 1: reward expected 0.0, got nan"),
        (
            "raise",
            "step 1: step expected a step, got UnprintableError: <str() raised RuntimeError>",
        ),
    ],
)
def test_a_value_the_replayed_game_returns_that_raises_is_a_divergence_not_a_traceback(
    rps: Path, field: str, described: str
) -> None:
    first, *_ = replay([rps], env_factory=lambda: _Spoiled(field)).episodes
    assert first.status == "not_replayable" and first.divergence is not None
    assert first.divergence.describe().startswith(described)


def test_recorded_env_kwargs_are_bounded_before_a_game_env_is_built(
    rps: Path, tmp_path: Path
) -> None:
    def run(meta: dict[str, str]) -> dict[str, str]:
        layout = json.loads(meta["layout"])
        layout["env_kwargs"] = {**layout["env_kwargs"], "extra": "x" * 70_000}
        return {**meta, "layout": json.dumps(layout)}

    evil = rewrite(rps, tmp_path / "big.mcap", run=run)
    results = replay([evil]).episodes
    assert {(e.status, e.reason) for e in results} == {
        (
            "not_replayable",
            "the recorded env kwarg 'extra' is 70002 bytes of JSON (all: 70003), more than the "
            "65536 replay builds an env from; pass --env-factory MODULE:CALLABLE that builds "
            "the env",
        )
    }


@pytest.mark.parametrize(
    ("factory", "message"),
    [
        (
            "tests.support.factories:raises",
            "--env-factory tests.support.factories:raises: it raised RuntimeError: boom from "
            "factory; it must take no arguments and return the env",
        ),
        (
            "tests.support.factories:not_an_env",
            "--env-factory tests.support.factories:not_an_env: it returned str, not a "
            "PettingZoo AECEnv or ParallelEnv",
        ),
    ],
    ids=["raises", "not-an-env"],
)
def test_an_env_factory_that_raises_or_returns_no_game_is_a_usage_error(
    rps: Path, factory: str, message: str
) -> None:
    """As for a Gymnasium file: the user's factory is at fault, not the file (one line, exit 2)."""
    with pytest.raises(ConfigurationError, match=f"^{re.escape(message)}$"):
        replay([rps], env_factory=factory)
    result = CliRunner().invoke(app, ["replay", str(rps), "--env-factory", factory])
    assert result.exit_code == 2, result.output
    assert result.stderr.strip() == f"episode-audit: error: {message}"


def test_an_env_factory_of_the_other_api_is_not_replayable(rps: Path) -> None:
    """A PettingZoo env of the API the file was not recorded with: the env does not match."""
    result = replay([rps], env_factory=rps_v2.env)
    assert {(e.status, e.reason) for e in result.episodes} == {
        (
            "not_replayable",
            "the env factory returned OrderEnforcingWrapper, not a PettingZoo ParallelEnv",
        )
    }


class _Doubled(BaseParallelWrapper):  # type: ignore[misc]
    """A reward wrapper of one's own: each reward doubled."""

    def step(self, actions: dict[str, Any]) -> tuple[Any, ...]:
        obs, rewards, term, trunc, infos = super().step(actions)
        return obs, {a: 2 * r for a, r in rewards.items()}, term, trunc, infos


def _doubled_rps() -> Any:
    return _Doubled(rps_v2.parallel_env(max_cycles=3))


WRAPPED = (
    "differed at step 0 (reward) in an env whose match with the recording could not be "
    'verified: the recorded env\'s wrappers ("_Doubled", "aec_to_parallel_wrapper") are not '
    'the rebuilt env\'s ("aec_to_parallel_wrapper"), and may change a step; pass --env-factory '
    "MODULE:CALLABLE that builds the env with them"
)


def test_a_game_recorded_over_a_wrapper_replay_does_not_rebuild_is_not_diverged(
    tmp_path: Path,
) -> None:
    """Replay builds rps from its id and kwargs, without the user's reward wrapper.

    The layout names the wrappers; the rebuilt env lacks one, so its rewards differing says
    nothing of the env: not_replayable, naming both sides' wrappers. The user's factory with the
    wrapper replays it identical.
    """
    path = tmp_path / "doubled.mcap"
    with RecordParallelEvidence(_doubled_rps(), path, env_kwargs={"max_cycles": 3}) as env:
        env.reset(seed=0)
        while env.agents:
            env.step({"player_0": 1, "player_1": 2})  # paper against scissors: rewards -2, 2
    assert open_evidence(path).run.layout["wrappers"] == [
        f"{__name__}._Doubled",
        "pettingzoo.utils.conversions.aec_to_parallel_wrapper",
        "pettingzoo.utils.wrappers.order_enforcing.OrderEnforcingWrapper",
        "pettingzoo.utils.wrappers.assert_out_of_bounds.AssertOutOfBoundsWrapper",
    ]
    result = replay([path])
    assert [(e.status, e.reason) for e in result.episodes] == [("not_replayable", WRAPPED)] * 2
    assert result.episodes[0].divergence is not None
    assert result.episodes[0].divergence.describe().startswith("step 0: reward expected -2.0")
    assert replay([path], env_factory=_doubled_rps).count("identical") == 2


def test_an_aec_game_recorded_over_multi_episode_env_is_not_diverged(tmp_path: Path) -> None:
    """MultiEpisodeEnv plays two tictactoe games as one; replay's tictactoe plays one."""
    path = tmp_path / "multi.mcap"
    with RecordAECEvidence(
        MultiEpisodeEnv(tictactoe_v3.env(), num_episodes=2), path, env_kwargs={}
    ) as env:
        env.reset(seed=0)
        moves = iter([0, 3, 1, 4, 2] * 2)  # player_1 completes the top row, twice
        for _agent in env.agent_iter():
            _, _, terminated, truncated, _ = env.last()
            env.step(None if terminated or truncated else next(moves))
    result = replay([path])
    assert {e.status for e in result.episodes} == {"not_replayable"}
    assert all(
        '("MultiEpisodeEnv", "TerminateIllegalWrapper") are not the rebuilt env\'s '
        '("TerminateIllegalWrapper")' in str(e.reason)
        for e in result.episodes
    ), result.to_dict()


def test_other_spaces_in_a_game_recorded_without_env_kwargs_say_to_record_them(
    tmp_path: Path,
) -> None:
    """go's board_size changes its spaces; the recorder was not told it (no env_kwargs=)."""
    path = tmp_path / "go.mcap"
    with RecordAECEvidence(go_v5.env(board_size=5), path) as env:
        env.reset(seed=0)
        env.step(0)
    reasons = {e.reason for e in replay([path]).episodes}
    assert len(reasons) == 1
    assert re.fullmatch(
        r"the rebuilt env does not match the recording: observation space .* recorded vs .* "
        r"rebuilt; the file holds no env_kwargs \(the env's constructor arguments, which the "
        r"recorder takes as env_kwargs=\): record with them, or pass --env-factory "
        r"MODULE:CALLABLE that builds the env as recorded",
        reasons.pop() or "",
    )


def test_games_after_the_recording_called_render_are_not_diverged(tmp_path: Path) -> None:
    """Pistonball's observations are its screen, which render() redraws; replay never renders.

    The loop renders after each step of game 0: from its 8th step on, the replay's
    observations differ, and it says why they cannot be compared instead of calling them
    diverged.
    """
    kwargs = {"n_pistons": 4, "max_cycles": 10, "render_mode": "rgb_array"}
    path = tmp_path / "rendered.mcap"
    with RecordParallelEvidence(
        pistonball_v6.parallel_env(**kwargs), path, env_kwargs=kwargs
    ) as env:
        for seed in (0, 1):
            env.reset(seed=seed)
            step = 0
            while env.agents:
                env.step(
                    {
                        agent: np.full(1, (-1.0) ** (step + i), dtype=np.float32)
                        for i, agent in enumerate(env.agents)
                    }
                )
                step += 1
                if seed == 0:
                    env.render()
    result = replay([path])
    assert {e.status for e in result.episodes} == {"identical", "not_replayable"}
    why = (
        " in an env whose match with the recording could not be verified: the recording called "
        "render() (first in game 0), which replay does not: an env's steps may depend on it "
        "(pistonball's observations are the screen render() redraws); record without render() "
        "calls to verify them"
    )
    assert all(
        str(e.reason).startswith("differed at step ") and str(e.reason).endswith(why)
        for e in result.episodes
        if e.status != "identical"
    ), result.to_dict()
    assert "recorder_note:rendered" in {f.code for f in check([path]).findings}
