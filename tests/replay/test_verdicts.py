"""Replay's verdicts: per-sub-env replay, causes classified before comparing, real divergence."""

from __future__ import annotations

import json
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pyarrow as pa
import pytest
from typer.testing import CliRunner

from episode_audit import (
    RecordEvidence,
    RecordParallelEvidence,
    RecordVectorEvidence,
    check,
    open_evidence,
)
from episode_audit.cli import app
from episode_audit.format import names as fmt
from episode_audit.replay import replay
from tests.support.hostile import replace_column, rewrite
from tests.support.limits import record_two_episodes, skipping_pendulum
from tests.support.mission import mission_env
from tests.support.stateful import (
    cartpole8,
    counted_cartpole,
    mutating_cartpole,
    normalized_cartpole,
    random_module_cartpole,
)


def record_vector(path: Path, vectorization: str, n: int = 3, steps: int = 60) -> Path:
    """Random steps of ``n`` CartPoles, each in its own episode counter."""
    make = gym.vector.SyncVectorEnv if vectorization == "sync" else gym.vector.AsyncVectorEnv
    envs: Any = make([counted_cartpole] * n)
    with RecordVectorEvidence(envs, path) as rec:
        rec.reset(seed=11)
        rec.action_space.seed(3)
        for _ in range(steps):
            rec.step(rec.action_space.sample())
    return path


@pytest.mark.parametrize("vectorization", ["sync", "async"])
def test_each_sub_env_replays_in_its_own_env_in_recorded_order(
    tmp_path: Path, vectorization: str
) -> None:
    path = record_vector(tmp_path / "v.mcap", vectorization)
    result = replay([path], env_factory=counted_cartpole)
    statuses = [(e.episode, e.status, e.divergence) for e in result.episodes]
    assert len(statuses) > 12
    assert all(s == "identical" for _, s, _ in statuses), statuses


def test_an_env_keeping_state_across_resets_is_replayed_in_recorded_order_never_diverged(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Its observations count its resets: an episode replayed in a fresh env (a selection, or
    # a batch of a large file) differs from the recording with nothing wrong.
    path = tmp_path / "counted.mcap"
    with RecordEvidence(counted_cartpole(), path) as env:
        run_episodes(env, 12)
    alone = replay([path], episodes=[9, 3], env_factory=counted_cartpole)
    assert [(e.episode, e.status) for e in alone.episodes] == [(3, "identical"), (9, "identical")]
    from episode_audit.replay import run as replay_run

    monkeypatch.setattr(replay_run, "MIN_BATCH_BYTES", path.stat().st_size // 4)
    assert len(replay_run._batches([path], None, None, 2)[0]) == 4
    batched = replay([path], env_factory=counted_cartpole, jobs=2)
    assert [e.status for e in batched.episodes] == ["identical"] * 12
    # a real difference still diverges, in recorded order: a fresh counter each episode
    fresh = replay([path], episodes=[4, 5], env_factory=cartpole_counted_afresh)
    assert [(e.episode, e.status) for e in fresh.episodes] == [(4, "diverged"), (5, "diverged")]
    assert fresh.episodes[0].restored == "seed 104; this env after 4 earlier episodes"


def test_an_episode_reset_and_never_stepped_replays_in_recorded_order(tmp_path: Path) -> None:
    # (it was replayed after every episode with rows: in an env that counts its resets, the
    # episodes after it then diverged at their reset)
    path = tmp_path / "unstarted.mcap"
    with RecordEvidence(counted_cartpole(), path) as env:
        env.reset(seed=1)  # never stepped: an episode with no rows
        env.reset(seed=2)
        for _ in range(5):
            env.step(0)
        env.reset(seed=3)
        env.step(1)
    result = replay([path], env_factory=counted_cartpole)
    assert [(e.episode, e.status) for e in result.episodes] == [(1, "identical"), (2, "identical")]
    assert result.unstarted == 1  # (listed apart, as check and report count it)
    alone = replay([path], episodes=[2], env_factory=counted_cartpole)
    assert [(e.episode, e.status) for e in alone.episodes] == [(2, "identical")]


def test_a_file_ending_in_a_reset_counts_that_episode_apart_as_check_does(
    tmp_path: Path,
) -> None:
    """A reset the loop never stepped (then closed) is no episode to verify: ``check`` and
    ``show`` count it apart, and so does replay, which listed it as replayed."""
    path = tmp_path / "ends-in-a-reset.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        for seed in (0, 1):
            env.reset(seed=seed)
            for _ in range(5):
                env.step(0)
        env.reset(seed=2)  # never stepped
    assert check([path]).episodes == 2
    result = replay([path])
    assert [(e.episode, e.status) for e in result.episodes] == [(0, "identical"), (1, "identical")]
    assert result.unstarted == 1 and result.ok and not result.missing
    shown = CliRunner().invoke(app, ["replay", str(path)])
    assert shown.exit_code == 0, shown.output
    assert shown.stdout.strip() == (
        "2 identical, 0 diverged, 0 not replayable: 2 episode(s) verified (+1 unstarted)"
    )
    data = json.loads(CliRunner().invoke(app, ["replay", str(path), "--format", "json"]).stdout)
    assert data["summary"]["unstarted"] == 1 and len(data["episodes"]) == 2
    alone = CliRunner().invoke(app, ["replay", str(path), "--episode", "2"])
    assert alone.exit_code == 1
    assert alone.stderr.strip() == (
        "episode-audit: error: replay verified no episode: the file(s) hold no episode but 1 "
        "unstarted (reset and never stepped); pass --allow-unverified when that is expected"
    )


def cartpole_counted_afresh() -> gym.Env[Any, Any]:
    """CartPole in an :class:`EpisodeCount` that forgets its count at every reset."""
    env = counted_cartpole()
    reset = env.reset

    def forgetting(**kwargs: Any) -> Any:
        env.resets = 0  # type: ignore[attr-defined]
        return reset(**kwargs)

    env.reset = forgetting  # type: ignore[method-assign]
    return env


def run_episodes(env: Any, episodes: int, seed: int = 100) -> None:
    env.action_space.seed(seed)
    for e in range(episodes):
        env.reset(seed=seed + e)
        done = False
        while not done:
            _, _, term, trunc, _ = env.step(env.action_space.sample())
            done = term or trunc


def test_warmed_up_normalize_observation_replays_from_its_snapshots_never_diverged(
    tmp_path: Path,
) -> None:
    env = normalized_cartpole()
    run_episodes(env, 5, seed=1)  # warmed up: the statistics are snapshot at every reset
    path = tmp_path / "n.mcap"
    with RecordEvidence(env, path) as rec:  # no warning: its state is restorable
        run_episodes(rec, 6)
    for factory in (None, normalized_cartpole):
        result = replay([path], env_factory=factory)
        assert [e.status for e in result.episodes] == ["identical"] * 6
    assert not [f for f in check([path]).findings if f.code == "not_replayable"]


def test_vector_wrapper_under_the_recorder_is_recorded_warned_and_not_replayable(
    tmp_path: Path,
) -> None:
    envs: Any = gym.vector.SyncVectorEnv([cartpole8] * 2)
    envs = gym.wrappers.vector.NormalizeObservation(gym.wrappers.vector.ClipReward(envs, 0, 1))
    path = tmp_path / "vw.mcap"
    with pytest.warns(UserWarning, match=r"RecordVectorEvidence: the recorder wrapped") as caught:
        rec = RecordVectorEvidence(envs, path)
    warned = [str(w.message) for w in caught]
    assert len(warned) == 2  # one warning per cause, the innermost first
    assert "the vector wrapper ClipReward (gymnasium.wrappers.vector." in warned[0]
    assert "the vector wrapper NormalizeObservation" in warned[1]
    assert "wrap the vector env in RecordVectorEvidence first (innermost)" in warned[1]
    with rec:
        rec.reset(seed=1)
        for _ in range(20):
            rec.step(rec.action_space.sample())
    ev = open_evidence(path)
    assert ev.run.layout["vector_wrappers"] == [
        "gymnasium.wrappers.vector.vectorize_reward:ClipReward",
        "gymnasium.wrappers.vector.stateful_observation:NormalizeObservation",
    ]
    result = replay([path], env_factory=cartpole8)
    assert result.count("diverged") == 0
    assert result.count("not_replayable") == len(result.episodes) > 2
    reason = result.episodes[0].reason or ""
    assert "vector wrapper ClipReward" in reason and "vector wrapper NormalizeObservation" in reason
    findings = [f.message for f in check([path]).findings if f.code == "not_replayable"]
    assert len(findings) == 2
    assert "ClipReward" in findings[0] and "NormalizeObservation" in findings[1]


def test_pistonball_rebuilt_with_other_agents_names_the_difference(tmp_path: Path) -> None:
    pytest.importorskip("pymunk")
    with warnings.catch_warnings():  # PettingZoo 1.27 deprecates the env modules
        warnings.simplefilter("ignore", DeprecationWarning)
        from pettingzoo.butterfly import pistonball_v6

    path = tmp_path / "pb.mcap"
    with RecordParallelEvidence(pistonball_v6.parallel_env(n_pistons=5, max_cycles=3), path) as env:
        env.reset(seed=1)
        while env.agents:
            env.step({a: env.action_space(a).sample() for a in env.agents})
    result = replay([path])
    assert {e.status for e in result.episodes} == {"not_replayable"}
    assert len(result.episodes) == 5
    reason = result.episodes[0].reason or ""
    assert reason == (
        "the rebuilt env does not match the recording: agents 5 (piston_0 ... piston_4) "
        "recorded vs 20 (piston_0 ... piston_19) rebuilt; the file holds no env_kwargs (the "
        "env's constructor arguments, which the recorder takes as env_kwargs=): record with "
        "them, or pass --env-factory MODULE:CALLABLE that builds the env as recorded"
    ), reason


def _rps(max_cycles: int) -> Any:
    with warnings.catch_warnings():  # PettingZoo 1.27 deprecates the env modules
        warnings.simplefilter("ignore", DeprecationWarning)
        from pettingzoo.classic import rps_v2

    return rps_v2.parallel_env(max_cycles=max_cycles)


def _rps_game(path: Path, env_kwargs: dict[str, Any] | None) -> Path:
    env = _rps(4)
    with RecordParallelEvidence(env, path, env_kwargs=env_kwargs) as rec:
        rec.reset(seed=0)
        while rec.agents:
            rec.step(dict.fromkeys(rec.agents, 1))
    return path


def test_a_game_rebuilt_with_other_max_cycles_is_named_not_diverged(tmp_path: Path) -> None:
    """rps_v2 with max_cycles=4 and no env_kwargs: replay rebuilds the default 15 cycles."""
    result = replay([_rps_game(tmp_path / "rps.mcap", None)])
    assert [e.status for e in result.episodes] == ["not_replayable"] * 2
    assert result.episodes[0].reason == (
        "the rebuilt env does not match the recording: max_cycles 4 recorded vs 15 rebuilt; "
        "the file holds no env_kwargs (the env's constructor arguments, which the recorder "
        "takes as env_kwargs=): record with them, or pass --env-factory MODULE:CALLABLE that "
        "builds the env as recorded"
    )
    again = replay([_rps_game(tmp_path / "kw.mcap", {"max_cycles": 4})])
    assert [e.status for e in again.episodes] == ["identical"] * 2
    made = replay([tmp_path / "rps.mcap"], env_factory=lambda: _rps(5))
    assert made.episodes[0].reason == (
        "the rebuilt env does not match the recording: max_cycles 4 recorded vs 5 rebuilt; "
        "make the --env-factory build the env as recorded"
    )


@pytest.mark.parametrize(
    ("factory", "reason"),
    [
        (
            "tests.support.stateful:cartpole8",
            "the rebuilt env does not match the recording: max episode steps 5 recorded vs 8 "
            "rebuilt; make the --env-factory build the env as recorded",
        ),
        (
            "tests.support.stateful:mountain_car5",
            "the rebuilt env does not match the recording: observation space "
            '{"dtype": "float32", "high": [4.800000190734863, "inf"',
        ),
    ],
)
def test_a_rebuilt_env_that_differs_is_named_not_diverged(
    tmp_path: Path, factory: str, reason: str
) -> None:
    path = tmp_path / "cp.mcap"
    with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=5), path) as env:
        run_episodes(env, 2)
    result = replay([path], env_factory=factory)
    assert [e.status for e in result.episodes] == ["not_replayable"] * 2
    assert (result.episodes[0].reason or "").startswith(reason), result.episodes[0].reason


def test_an_env_kwarg_the_rebuilt_env_has_otherwise_is_named(tmp_path: Path) -> None:
    path = tmp_path / "fl.mcap"
    with RecordEvidence(gym.make("FrozenLake-v1", is_slippery=False), path) as env:
        run_episodes(env, 1)
    result = replay([path], env_factory=lambda: gym.make("FrozenLake-v1", is_slippery=True))
    assert result.episodes[0].reason == (
        "the rebuilt env does not match the recording: env kwarg 'is_slippery' false recorded "
        "vs true rebuilt; make the --env-factory build the env as recorded"
    )


@pytest.mark.parametrize(
    ("factory", "where", "field"),
    [(random_module_cartpole, None, "reset_observation"), (mutating_cartpole, 0, "reward")],
    ids=["random-module-reset", "mutating-wrapper"],
)
def test_real_nondeterminism_still_diverges_at_the_right_step(
    tmp_path: Path, factory: Any, where: int | None, field: str
) -> None:
    path = tmp_path / "nd.mcap"
    with RecordEvidence(factory(), path) as env:
        run_episodes(env, 3)
    result = replay([path], env_factory=factory)
    assert [e.status for e in result.episodes] == ["diverged"] * 3
    divergence = result.episodes[0].divergence
    assert divergence is not None
    assert (divergence.step, divergence.field) == (where, field)
    assert [e.restored for e in result.episodes] == [
        "seed 100; first episode in this env",
        "seed 101; this env after 1 earlier episode",
        "seed 102; this env after 2 earlier episodes",
    ]


def test_a_divergence_names_the_rng_state_and_the_sub_env_it_restored(tmp_path: Path) -> None:
    path = tmp_path / "v.mcap"
    envs: Any = gym.vector.SyncVectorEnv([mutating_cartpole] * 2)
    with RecordVectorEvidence(envs, path) as rec:
        rec.reset(seed=5)  # seeded once: every later reset of a sub-env is unseeded
        rec.action_space.seed(3)
        for _ in range(20):
            rec.step(rec.action_space.sample())
    result = replay([path], env_factory=mutating_cartpole)
    by_env: dict[int, list[str | None]] = {}
    for e in result.episodes:
        assert e.status == "diverged", e
        env_index = int(open_evidence(path).episodes().to_pylist()[e.episode]["env_index"])
        by_env.setdefault(env_index, []).append(e.restored)
    assert by_env[1][:2] == [
        "seed 6; first episode in sub-env 1's env",
        "the recorded RNG state (an unseeded reset); sub-env 1's env after 1 earlier episode",
    ]
    args = ["replay", str(path), "--env-factory", "tests.support.stateful:mutating_cartpole"]
    shown = CliRunner().invoke(app, [*args, "--format", "markdown"])
    assert shown.exit_code == 1
    assert "(restored: seed 5; first episode in sub-env 0's env) |" in shown.stdout
    as_json = json.loads(CliRunner().invoke(app, [*args, "--format", "json"]).stdout)
    assert as_json["episodes"][0]["restored"] == "seed 5; first episode in sub-env 0's env"


def record_missions(path: Path, episodes: int = 4) -> Path:
    """Random steps of :class:`MissionEnv`: a Dict observation with a space of its own class."""
    with RecordEvidence(mission_env(), path) as rec:
        rec.action_space.seed(1)
        for e in range(episodes):
            rec.reset(seed=e)
            done = False
            while not done:
                _, _, term, trunc, _ = rec.step(rec.action_space.sample())
                done = term or trunc
    return path


def test_an_unknown_sub_space_is_stored_as_json_and_the_file_replays(tmp_path: Path) -> None:
    path = record_missions(tmp_path / "m.mcap")
    ev = open_evidence(path)
    stored = ev.steps_schema.field("observation").type
    assert str(stored) == "struct<mission: string, pos: fixed_size_list<item: float>[2]>"
    result = replay([path], env_factory=mission_env)
    assert [(e.status, e.reason) for e in result.episodes] == [("identical", None)] * 4
    notes = [(f.severity, f.code, f.message) for f in check([path]).findings]
    assert (
        "note",
        "observation_space_unchecked",
        "observation['mission']: MissionSpace is not a Gymnasium space episode-audit knows: "
        "stored as JSON; its values were not checked against it",
    ) in notes
    assert not [n for n in notes if n[1] == "not_replayable"]


def test_the_cli_replays_a_file_with_an_unknown_sub_space(tmp_path: Path) -> None:
    path = record_missions(tmp_path / "m.mcap", episodes=2)
    factory = "tests.support.mission:mission_env"
    result = CliRunner().invoke(app, ["replay", str(path), "--env-factory", factory])
    assert result.exit_code == 0, result.output
    assert "2 identical, 0 diverged, 0 not replayable" in result.stdout


def tampered_cartpole(tmp_path: Path, versions: dict[str, str]) -> Path:
    """Three CartPole episodes with episode 0's step 2 reward changed, recorded ``versions``."""
    path = tmp_path / "cartpole.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        run_episodes(env, 3)

    def run(meta: dict[str, str]) -> dict[str, str]:
        return {**meta, "versions": json.dumps({**json.loads(meta["versions"]), **versions})}

    def steps(batch: pa.RecordBatch) -> pa.RecordBatch:
        rewards = batch.column(fmt.COL_REWARD).to_pylist()
        rewards[2] = 1.5
        return replace_column(batch, fmt.COL_REWARD, rewards)

    return rewrite(path, tmp_path / "tampered.mcap", run=run, steps=steps)


def test_a_difference_replayed_with_other_env_library_versions_is_not_a_divergence(
    tmp_path: Path,
) -> None:
    path = tampered_cartpole(tmp_path, {"numpy": "1.0.0", "python": "2.7.18"})
    result = replay([path])
    first, *others = result.episodes
    assert [e.status for e in others] == ["identical", "identical"]
    assert first.status == "not_replayable" and first.divergence is not None
    assert (first.divergence.step, first.divergence.field) == (2, "reward")
    assert first.reason == (
        "differed at step 2 (reward) with other versions of python, numpy than recorded: a "
        "difference cannot be told from theirs; replay where they match to verify, or allow for "
        "them with --atol"
    )
    assert result.ok and result.verified == 2
    assert result.version_differences[str(path)]["numpy"] == ("1.0.0", np.__version__)
    shown = CliRunner().invoke(app, ["replay", str(path), "--format", "markdown"])
    assert shown.exit_code == 0, shown.output
    assert "| not_replayable |" in shown.stdout and "other versions of python" in shown.stdout
    assert "Library versions differ from the recording" in shown.stdout
    as_json = json.loads(CliRunner().invoke(app, ["replay", str(path), "-f", "json"]).stdout)
    assert as_json["episodes"][0]["divergence"]["field"] == "reward"


@pytest.mark.parametrize("library", ["pyarrow", "mcap", "jax", "os"])
def test_versions_of_libraries_no_replayed_step_used_leave_a_divergence_a_divergence(
    tmp_path: Path, library: str
) -> None:
    """pyarrow and mcap read the file; jax (not installed here) the rebuilt env did not load;
    no recorder records a version of ``os`` (a hand-edited file's)."""
    assert library != "jax" or "jax" not in sys.modules
    path = tampered_cartpole(tmp_path, {library: "0.0.1"})
    result = replay([path])
    assert [e.status for e in result.episodes] == ["diverged", "identical", "identical"]
    assert result.version_differences[str(path)][library][0] == "0.0.1"
    assert not result.ok


def test_an_env_recorded_without_a_time_limit_is_rebuilt_without_one(tmp_path: Path) -> None:
    """``gym.make(id).unwrapped`` has no TimeLimit: its spec says ``max_episode_steps: null``,
    and the registered 200-step limit must not come back in replay."""
    path = tmp_path / "bare.mcap"
    env = gym.make("Pendulum-v1").unwrapped
    env.action_space.seed(0)
    with RecordEvidence(env, path) as rec:
        rec.reset(seed=0)
        for _ in range(230):
            rec.step(rec.action_space.sample())
    assert open_evidence(path).run.env_spec["max_episode_steps"] is None
    result = replay([path])
    assert [(e.status, e.steps) for e in result.episodes] == [("identical", 230)]


def test_a_time_limit_the_recording_had_not_is_named_not_diverged(tmp_path: Path) -> None:
    path = tmp_path / "bare.mcap"
    env = gym.make("Pendulum-v1").unwrapped
    env.action_space.seed(0)
    with RecordEvidence(env, path) as rec:
        rec.reset(seed=0)
        for _ in range(210):
            rec.step(rec.action_space.sample())
    result = replay([path], env_factory=lambda: gym.make("Pendulum-v1"))
    assert result.episodes[0].reason == (
        "the rebuilt env does not match the recording: max episode steps null recorded vs 200 "
        "rebuilt; make the --env-factory build the env as recorded"
    )


def test_a_factory_without_the_recorded_time_limit_is_named_not_diverged(tmp_path: Path) -> None:
    path = tmp_path / "limited.mcap"
    with RecordEvidence(gym.wrappers.TimeLimit(gym.make("Pendulum-v1").unwrapped, 30), path) as rec:
        rec.reset(seed=0)
        for _ in range(30):
            rec.step(rec.action_space.sample())
    result = replay([path], env_factory=lambda: gym.make("Pendulum-v1").unwrapped)
    assert result.episodes[0].reason == (
        "the rebuilt env does not match the recording: max episode steps 30 recorded vs null "
        "rebuilt; make the --env-factory build the env as recorded"
    )


def _nested_limits() -> gym.Env[Any, Any]:
    """Pendulum in its registered 200-step limit, in a larger one: the inner one ends it."""
    return gym.wrappers.TimeLimit(gym.make("Pendulum-v1"), 500)


@pytest.mark.parametrize("factory", [None, _nested_limits], ids=["rebuilt", "env-factory"])
def test_an_inner_time_limit_ending_episodes_replays_identical(
    tmp_path: Path, factory: Any
) -> None:
    path = tmp_path / "nested.mcap"
    with RecordEvidence(_nested_limits(), path) as rec:
        rec.action_space.seed(0)
        for seed in (0, 1):
            rec.reset(seed=seed)
            for _ in range(200):
                rec.step(rec.action_space.sample())
    result = replay([path], env_factory=factory)
    assert [(e.status, e.steps) for e in result.episodes] == [("identical", 200)] * 2


@pytest.mark.parametrize("factory", [None, "factory"], ids=["rebuilt", "env-factory"])
@pytest.mark.parametrize(("limit", "length"), [(30, 30), (60, 50)], ids=["outer", "inner"])
def test_a_time_limit_over_a_frame_skip_replays_identical(
    tmp_path: Path, factory: Any, limit: int, length: int
) -> None:
    """Rebuilt where it was, over the frame skip (not right over the env, where it would count
    the env's steps: 4 per step); the registered one under it ends episodes at step 50."""
    path = record_two_episodes(tmp_path / "skip.mcap", skipping_pendulum(limit), length)
    made = None if factory is None else lambda: skipping_pendulum(limit)
    result = replay([path], env_factory=made)
    assert [(e.status, e.steps) for e in result.episodes] == [("identical", length)] * 2


def test_an_env_without_the_time_limit_over_the_frame_skip_does_not_match(tmp_path: Path) -> None:
    path = record_two_episodes(tmp_path / "skip.mcap", skipping_pendulum(30), 30)
    same_limits = lambda: gym.wrappers.MaxAndSkipObservation(  # noqa: E731
        gym.make("Pendulum-v1", max_episode_steps=200), skip=4
    )
    result = replay([path], env_factory=same_limits)
    assert {e.reason for e in result.episodes} == {
        "the rebuilt env does not match the recording: time limits over multi-step wrappers "
        "[30] recorded vs [] rebuilt; make the --env-factory build the env as recorded"
    }


def test_a_file_with_the_smallest_time_limit_as_its_spec_still_replays_in_its_env(
    tmp_path: Path,
) -> None:
    """A file whose spec has the smallest limit and no TimeLimit among its wrappers (as the
    recorder wrote them before placing them): the env factory that built it still replays it."""
    path = record_two_episodes(tmp_path / "skip.mcap", skipping_pendulum(30), 30)

    def smallest(meta: dict[str, str]) -> dict[str, str]:
        spec = json.loads(meta["env_spec"])
        spec["max_episode_steps"] = 30
        spec["additional_wrappers"] = spec["additional_wrappers"][:1]
        return {**meta, "env_spec": json.dumps(spec)}

    old = rewrite(path, tmp_path / "old.mcap", run=smallest)
    result = replay([old], env_factory=lambda: skipping_pendulum(30))
    assert [(e.status, e.steps) for e in result.episodes] == [("identical", 30)] * 2


@pytest.mark.parametrize(
    ("later", "why"),
    [
        (20, "recorded truncated by its time limit at step 19, where the rebuilt env's limits "),
        (80, "the rebuilt env's time limit truncated it at step 49, where the recorded episode "),
    ],
    ids=["lowered", "raised"],
)
def test_a_time_limit_changed_after_the_recorder_was_made_is_no_divergence(
    tmp_path: Path, later: int, why: str
) -> None:
    """The file's spec has the limit the recorder was made over; the episodes after the change
    end elsewhere than the rebuilt env's (each labelled as it ended)."""
    path = tmp_path / "changed.mcap"
    env = gym.make("Pendulum-v1", max_episode_steps=50)
    with RecordEvidence(env, path) as rec:
        rec.action_space.seed(0)
        for seed, steps in ((0, 50), (1, min(later, 60))):
            rec.reset(seed=seed)
            for _ in range(steps):
                rec.step(rec.action_space.sample())
            env.set_wrapper_attr("_max_episode_steps", later)
    ev = open_evidence(path)
    assert ev.run.env_spec is not None and ev.run.env_spec["max_episode_steps"] == 50
    result = replay([path])
    assert [e.status for e in result.episodes] == ["identical", "not_replayable"]
    assert (result.episodes[1].reason or "").startswith(why)
    assert (result.episodes[1].reason or "").endswith(
        "the rebuilt env's TimeLimits are not those it was recorded in (a limit set after the "
        "recorder was made, say); build it with the limits it ran under"
    )


def _record_vector(path: Path, envs: Any, steps: int) -> Any:
    with RecordVectorEvidence(envs, path) as rec:
        rec.action_space.seed(0)
        rec.reset(seed=0)
        for _ in range(steps):
            rec.step(rec.action_space.sample())
    return open_evidence(path)


_ASYNC = (
    "the sub-envs ran in AsyncVectorEnv workers, whose wrapper chains the recorder cannot walk: "
    "it read the outermost TimeLimit's limit only (one inside it, or under a frame-skipping "
    "wrapper, it did not); record with SyncVectorEnv to replay such endings"
)


def test_time_limits_async_workers_hide_are_not_called_divergences(tmp_path: Path) -> None:
    """A worker answers for its outermost TimeLimit only: the file cannot say where the others
    were, or that one ended an episode (recorded external). Rebuilt from the spec, with the
    outermost limit only, the env does not truncate there. (Under a frame skip, only an env
    factory says where they were: tests/replay/test_worker_limits.py.)"""
    ev = _record_vector(
        tmp_path / "async.mcap", gym.vector.AsyncVectorEnv([_nested_limits] * 2), 201
    )
    assert ev.run.layout["unread_time_limits"] == _ASYNC
    result = replay([ev.path])
    why = "recorded truncated (external) at step 199, where the rebuilt env did not truncate"
    assert [(e.status, e.reason) for e in result.episodes[:2]] == [
        ("not_replayable", f"{why}: {_ASYNC}")
    ] * 2


def test_an_unread_limit_the_env_factory_ends_the_episode_at_replays_identical(
    tmp_path: Path,
) -> None:
    """The recorder could not read the limit under the frame skip (the workers hid it) and said
    external; the env factory's limit truncates each episode at that same step, every value
    equal: the same ending, labelled as the recorder could."""
    envs = gym.vector.AsyncVectorEnv([skipping_pendulum] * 2)
    ev = _record_vector(tmp_path / "async.mcap", envs, 51)
    assert ev.run.layout["unread_time_limits"] == _ASYNC
    ended = [e for e in ev.episodes().to_pylist() if e["outcome"] != "incomplete"]
    assert [(e["length"], e["truncation_reason"]) for e in ended] == [(50, "external")] * 2
    result = replay([ev.path], env_factory=skipping_pendulum)
    assert [(e.status, e.steps, e.reason) for e in result.episodes[:2]] == [
        ("identical", 50, None)
    ] * 2


def test_a_file_from_async_workers_without_the_layout_key_says_the_same(tmp_path: Path) -> None:
    """Files recorded before the recorder wrote ``unread_time_limits``: the workers say it."""
    ev = _record_vector(tmp_path / "a.mcap", gym.vector.AsyncVectorEnv([_nested_limits] * 2), 201)

    def unsaid(meta: dict[str, str]) -> dict[str, str]:
        layout = json.loads(meta["layout"])
        layout.pop("unread_time_limits", None)
        return {**meta, "layout": json.dumps(layout)}

    old = rewrite(ev.path, tmp_path / "old.mcap", run=unsaid)
    assert "unread_time_limits" not in open_evidence(old).run.layout
    result = replay([old])
    assert [e.status for e in result.episodes] == ["not_replayable"] * 2
    assert result.unstarted == 2 and (result.episodes[0].reason or "").endswith(_ASYNC)


def test_a_same_step_autoreset_hiding_a_time_limit_under_a_frame_skip_is_said(
    tmp_path: Path,
) -> None:
    envs = gym.vector.SyncVectorEnv([skipping_pendulum] * 2, autoreset_mode="SameStep")
    ev = _record_vector(tmp_path / "same.mcap", envs, 51)
    cause = (
        "a sub-env's TimeLimit under MaxAndSkipObservation counts the env's own steps, and the "
        "SameStep autoreset zeroed its count before the recorder read it: its truncations are "
        "recorded external; record in NextStep mode to replay such endings"
    )
    assert ev.run.layout["unread_time_limits"] == cause
    ended = [e for e in ev.episodes().to_pylist() if e["outcome"] != "incomplete"]
    assert [(e["length"], e["truncation_reason"]) for e in ended] == [(50, "external")] * 2
    # rebuilt, its limit truncates them at that step: the same ending, every value equal
    result = replay([ev.path])
    assert [(e.status, e.steps) for e in result.episodes[:2]] == [("identical", 50)] * 2
    # where the rebuilt env does not truncate, the unread limit is said
    later = rewrite(ev.path, tmp_path / "later.mcap", run=_spec_limit(400))
    result = replay([later])
    why = "recorded truncated (external) at step 49, where the rebuilt env did not truncate"
    assert [(e.status, e.reason) for e in result.episodes[:2]] == [
        ("not_replayable", f"{why}: {cause}")
    ] * 2


def _spec_limit(limit: int) -> Callable[[dict[str, str]], dict[str, str]]:
    """A run metadata edit: the env spec's ``max_episode_steps`` made ``limit``."""

    def edit(meta: dict[str, str]) -> dict[str, str]:
        spec = json.loads(meta["env_spec"])
        spec["max_episode_steps"] = limit
        return {**meta, "env_spec": json.dumps(spec)}

    return edit


@pytest.mark.parametrize("coded", [True, False], ids=["coded", "without-cause"])
def test_a_same_step_file_s_unread_limits_are_coded_zeroed_not_workers(
    tmp_path: Path, coded: bool
) -> None:
    """Its cause code says the count was zeroed (no worker chain): replay rebuilds from the spec
    (a worker file's would not be: its spec holds a frame skip) and says the recorded cause; a
    file without the code says the same by its text."""
    envs = gym.vector.SyncVectorEnv([skipping_pendulum] * 2, autoreset_mode="SameStep")
    ev = _record_vector(tmp_path / "same.mcap", envs, 51)
    assert ev.run.layout["unread_time_limits_cause"] == "zeroed"
    cause = ev.run.layout["unread_time_limits"]

    def uncoded(meta: dict[str, str]) -> dict[str, str]:
        layout = json.loads(meta["layout"])
        del layout["unread_time_limits_cause"]
        return {**meta, "layout": json.dumps(layout)}

    path = ev.path if coded else rewrite(ev.path, tmp_path / "old.mcap", run=uncoded)
    assert [e.status for e in replay([path]).episodes[:2]] == ["identical"] * 2
    later = rewrite(path, tmp_path / "later.mcap", run=_spec_limit(400))
    result = replay([later])
    assert [e.status for e in result.episodes[:2]] == ["not_replayable"] * 2
    assert all((e.reason or "").endswith(cause) for e in result.episodes[:2])


def test_an_external_truncation_a_sync_env_does_not_repeat_still_diverges(tmp_path: Path) -> None:
    """Where the recorder read every TimeLimit, an external truncation is the env's own."""
    ev = _record_vector(tmp_path / "sync.mcap", gym.vector.SyncVectorEnv([_nested_limits] * 2), 3)

    def truncated(batch: pa.RecordBatch) -> pa.RecordBatch:
        flags = [i % 3 == 2 for i in range(batch.num_rows)]
        return replace_column(batch, "truncated", pa.array(flags))

    def external(batch: pa.RecordBatch) -> pa.RecordBatch:
        batch = replace_column(batch, "outcome", pa.array(["truncated"] * batch.num_rows))
        return replace_column(batch, "truncation_reason", pa.array(["external"] * batch.num_rows))

    tampered = rewrite(ev.path, tmp_path / "t.mcap", steps=truncated, episodes=external)
    result = replay([tampered])
    assert [e.status for e in result.episodes] == ["diverged"] * 2


def test_an_external_truncation_where_a_read_limit_ends_it_is_not_called_identical(
    tmp_path: Path,
) -> None:
    """Where the recorder read every TimeLimit, one that ended the episode was said
    ``time_limit``: an ending recorded external there is not the rebuilt env's."""
    path = record_two_episodes(
        tmp_path / "p.mcap", gym.make("Pendulum-v1", max_episode_steps=30), 30
    )

    def external(batch: pa.RecordBatch) -> pa.RecordBatch:
        return replace_column(batch, "truncation_reason", pa.array(["external"] * batch.num_rows))

    tampered = rewrite(path, tmp_path / "t.mcap", episodes=external)
    result = replay([tampered])
    why = "the rebuilt env's time limit truncated it at step 29, where the recording's did not"
    assert [(e.status, (e.reason or "")[: len(why)]) for e in result.episodes] == [
        ("not_replayable", why)
    ] * 2


def test_episodes_an_autoreset_under_the_recorder_began_replay_identical(tmp_path: Path) -> None:
    path = tmp_path / "autoreset.mcap"
    env = gym.wrappers.Autoreset(gym.make("Pendulum-v1", max_episode_steps=30))
    with RecordEvidence(env, path) as rec:
        rec.action_space.seed(0)
        rec.reset(seed=0)
        for _ in range(75):
            rec.step(rec.action_space.sample())
    result = replay([path])
    assert [(e.status, e.steps, e.reason) for e in result.episodes] == [
        ("identical", 30, None),
        ("identical", 30, None),
        ("identical", 13, None),
    ]
    assert [f.code for f in check([path]).findings if f.severity != "note"] == []
