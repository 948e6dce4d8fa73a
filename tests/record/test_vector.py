"""Vector-env recording (record/vector/): the issue's acceptance, per autoreset mode, Sync, Async.

A vector CartPole-v1 with 4 sub-envs is recorded for 2 000 steps in each mode; its episodes are
compared with the same sub-envs stepped by hand (independent envs seeded s + i, the same
actions), and every sub-env episode is replayed on its own.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import sys
import time
import warnings
from collections import Counter
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from mcap.reader import make_reader
from typer.testing import CliRunner

from episode_audit import (
    RecorderError,
    RecordVectorEvidence,
    ResetRngInfo,
    check,
    open_evidence,
    replay,
    report,
)
from episode_audit.cli import app
from episode_audit.errors import ConfigurationError
from episode_audit.format.records import unstarted
from episode_audit.record.vector.rng import SubEnvRng
from tests.support.batching import InfoReading, messages
from tests.support.envs import ScriptedEnv
from tests.support.limits import skipping_pendulum
from tests.support.unsaved import (
    UNSAVED_WARNING,
    assert_unseeded_episodes_are_not_replayable,
    short_pong,
)
from tests.support.worker_rng import (
    LIMIT,
    lambda_kwarg,
    locked_rng_made,
    raising_rng_made,
    rng_locked_rng,
    rng_raising_rng,
    rng_sealed_rng,
)

N = 4
STEPS = 2000
SEED = 11
MODES = [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP, AutoresetMode.DISABLED]
KINDS = ["sync", "async"]


def _actions() -> np.ndarray[Any, Any]:
    return np.random.default_rng(0).integers(0, 2, size=(STEPS, N))


def _record(path: Path, kind: str, mode: AutoresetMode, **make: Any) -> Path:
    envs = gym.make_vec(
        "CartPole-v1",
        N,
        vectorization_mode=kind,
        vector_kwargs={"autoreset_mode": mode},
        **make,
    )
    actions = _actions()
    with RecordVectorEvidence(envs, path, block_steps=300) as rec:
        rec.reset(seed=SEED)
        for t in range(STEPS):
            _, _, term, trunc, _ = rec.step(actions[t])
            if mode is AutoresetMode.DISABLED and (term | trunc).any():
                rec.reset(options={"reset_mask": term | trunc})
    return path


def _by_hand(mode: AutoresetMode) -> dict[int, list[tuple[int, float, bool]]]:
    """(length, return, ended) of every episode of each sub-env, stepped as its own env."""
    actions = _actions()
    out: dict[int, list[tuple[int, float, bool]]] = {}
    for i in range(N):
        env = gym.make("CartPole-v1")
        env.reset(seed=SEED + i)
        episodes: list[tuple[int, float, bool]] = []
        length, ret, autoreset_next = 0, 0.0, False
        for t in range(STEPS):
            if autoreset_next:  # NEXT_STEP: this vector step only resets the sub-env
                env.reset()
                autoreset_next = False
                continue
            _, reward, term, trunc, _ = env.step(int(actions[t, i]))
            length, ret = length + 1, ret + float(reward)
            if term or trunc:
                episodes.append((length, ret, True))
                length, ret = 0, 0.0
                if mode is AutoresetMode.NEXT_STEP:
                    autoreset_next = True
                else:
                    env.reset()
        if not autoreset_next:  # the episode begun last, cut off by close()
            episodes.append((length, ret, False))
        out[i] = episodes
        env.close()
    return out


@pytest.fixture(
    scope="module",
    params=[(k, m) for k in KINDS for m in MODES],
    ids=lambda p: f"{p[0]}-{p[1].value}",
)
def recorded(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> tuple[str, AutoresetMode, Path]:
    kind, mode = request.param
    # Async SAME_STEP: the sub-envs report their RNG state before each autoreset themselves.
    make = {"wrappers": [ResetRngInfo]} if (kind, mode) == ("async", mode.SAME_STEP) else {}
    path = tmp_path_factory.mktemp("vec") / f"{kind}-{mode.value}.mcap"
    return kind, mode, _record(path, kind, mode, **make)


def test_episodes_equal_the_sub_envs_stepped_by_hand(
    recorded: tuple[str, AutoresetMode, Path],
) -> None:
    _, mode, path = recorded
    ev = open_evidence(path)
    assert ev.finished and ev.multi_stream
    assert ev.run.layout["kind"] == "vector" and ev.run.layout["num_envs"] == N
    assert ev.run.layout["autoreset_mode"] == mode.value
    assert ev.run.env_id == "CartPole-v1"  # the sub-env, what replay rebuilds
    episodes = ev.episodes()
    hand = _by_hand(mode)
    for i in range(N):
        mine = episodes.filter(pc.equal(episodes["env_index"], i)).to_pylist()
        got = [(e["length"], e["return"], e["outcome"] != "incomplete") for e in mine]
        assert got == hand[i], f"sub-env {i}"
        assert mine[0]["seed"] == SEED + i
        assert all(e["seed"] is None and e["rng_state"] for e in mine[1:])
    assert sum(len(h) for h in hand.values()) == episodes.num_rows > 300


def test_no_phantom_reset_steps(recorded: tuple[str, AutoresetMode, Path]) -> None:
    _, mode, path = recorded
    ev = open_evidence(path)
    steps = ev.steps(columns=["episode", "step", "reward", "terminated", "truncated"])
    # CartPole pays 1 for every real step; an autoreset step would be a row with reward 0.
    assert pc.all(pc.equal(steps["reward"], 1.0)).as_py()
    hand_steps = sum(n for eps in _by_hand(mode).values() for n, _, _ in eps)
    assert steps.num_rows == hand_steps
    expected = STEPS * N - (hand_steps if mode is AutoresetMode.NEXT_STEP else STEPS * N)
    # NEXT_STEP: every vector step a sub-env spent resetting is a reset row, not a step row
    resets = ev.resets()
    if mode is AutoresetMode.NEXT_STEP:
        assert resets.num_rows == N + expected
    else:
        assert resets.num_rows == ev.episodes().num_rows
    assert sorted(resets["episode"].to_pylist()) == ev.episodes()["episode"].to_pylist()
    ends = pc.or_(steps["terminated"], steps["truncated"]).to_numpy(zero_copy_only=False)
    episode = steps["episode"].to_numpy()
    last = np.append(episode[1:] != episode[:-1], True)
    assert not (ends & ~last).any()  # nothing recorded after an episode's end


def test_every_sub_env_episode_replays_identically_on_its_own(
    recorded: tuple[str, AutoresetMode, Path],
) -> None:
    _, _, path = recorded
    result = replay([path])
    statuses = Counter(e.status for e in result.episodes)
    rows = open_evidence(path).episodes().num_rows  # (unstarted ones counted apart)
    assert statuses == {"identical": rows - result.unstarted}, [
        (e.episode, e.reason) for e in result.episodes if e.status != "identical"
    ][:3]


def test_check_and_report_by_env_index(recorded: tuple[str, AutoresetMode, Path]) -> None:
    _, _, path = recorded
    codes = {f.code for f in check([path]).findings}
    assert codes <= {"unlabeled_failure", "missing_terms", "incomplete_episode"}, codes
    grouped = report([path], by="env_index")
    assert [g.key for g in grouped.groups] == [str(i) for i in range(N)]
    episodes = open_evidence(path).episodes()
    started = episodes.filter(pa.array(~unstarted(episodes)))  # report leaves those out
    assert [g.episodes for g in grouped.groups] == [
        started.filter(pc.equal(started["env_index"], i)).num_rows for i in range(N)
    ]


def test_exported_steps_name_their_sub_env(
    recorded: tuple[str, AutoresetMode, Path], tmp_path: Path
) -> None:
    import pyarrow.parquet as pq

    from episode_audit import export

    _, _, path = recorded
    result = export([path], tmp_path / "out")
    steps = pq.read_table(result.steps_files[0])
    episodes = pq.read_table(result.episodes_file)
    assert steps.column_names[:3] == ["file", "env_index", "agent"]
    owner = dict(zip(episodes["episode"].to_pylist(), episodes["env_index"].to_pylist()))
    assert [owner[e] for e in steps["episode"].to_pylist()] == steps["env_index"].to_pylist()
    assert set(steps["env_index"].to_pylist()) == {0, 1, 2, 3}
    assert steps["agent"].null_count == steps.num_rows


def test_cli_check_report_replay_on_a_vector_file(tmp_path: Path) -> None:
    path = _record(tmp_path / "cli.mcap", "sync", AutoresetMode.NEXT_STEP)
    runner = CliRunner()
    checked = runner.invoke(app, ["check", str(path), "--format", "json"])
    assert checked.exit_code in (0, 1), checked.output
    codes = {f["code"] for f in json.loads(checked.stdout)["findings"]}
    assert codes <= {"unlabeled_failure", "missing_terms", "incomplete_episode"}
    reported = runner.invoke(app, ["report", str(path), "--by", "env_index", "--format", "json"])
    assert reported.exit_code == 0, reported.output
    assert [g["key"] for g in json.loads(reported.stdout)["groups"]] == ["0", "1", "2", "3"]
    replayed = runner.invoke(app, ["replay", str(path), "--format", "json"])
    assert replayed.exit_code == 0, replayed.output
    summary = json.loads(replayed.stdout)["summary"]
    assert summary["diverged"] == summary["not_replayable"] == 0 and summary["identical"] > 300
    shown = runner.invoke(app, ["show", str(path)])
    assert shown.exit_code == 0 and "vector: 4 sub-envs (SyncVectorEnv, NextStep)" in shown.stdout


def test_same_step_async_without_the_rng_wrapper_says_why(tmp_path: Path) -> None:
    path = tmp_path / "no-rng.mcap"
    envs = gym.make_vec(
        "CartPole-v1",
        2,
        vectorization_mode="async",
        vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP},
        max_episode_steps=5,
    )
    with RecordVectorEvidence(envs, path) as rec:
        rec.reset(seed=3)
        for _ in range(12):
            rec.step(np.zeros(2, dtype=np.int64))
    episodes = open_evidence(path).episodes().to_pylist()
    assert [e["seed"] for e in episodes[:2]] == [3, 4]
    autoreset = episodes[2:]
    assert autoreset and all(e["seed"] is None and e["rng_state"] is None for e in autoreset)
    findings = check([path]).findings
    why = [f.message for f in findings if f.code == "recorder_note:rng_state_unavailable"]
    assert why and "SAME_STEP" in why[0] and "ResetRngInfo" in why[0]
    assert any(f.code == "not_replayable" for f in findings)
    statuses = {e.episode: e.status for e in replay([path]).episodes}
    assert statuses[0] == statuses[1] == "identical"
    assert {statuses[e["episode"]] for e in autoreset} == {"not_replayable"}


def test_sync_same_step_wraps_the_sub_envs_in_place(tmp_path: Path) -> None:
    envs = gym.make_vec(
        "CartPole-v1", 2, vectorization_mode="sync", vector_kwargs={"autoreset_mode": "SameStep"}
    )
    with RecordVectorEvidence(envs, tmp_path / "w.mcap") as rec:
        assert isinstance(rec.unwrapped, SyncVectorEnv)
        assert all(isinstance(e, ResetRngInfo) for e in rec.unwrapped.envs)
        rec.reset(seed=0)
    assert open_evidence(tmp_path / "w.mcap").run.env_spec["additional_wrappers"] == []


def test_vector_entry_point_env_is_recorded_but_not_replayable(tmp_path: Path) -> None:
    path = tmp_path / "native.mcap"
    envs = gym.make_vec("CartPole-v1", 3)  # CartPoleVectorEnv: no sub-envs
    with RecordVectorEvidence(envs, path) as rec:
        rec.reset(seed=0)
        for _ in range(60):
            rec.step(rec.action_space.sample())
    ev = open_evidence(path)
    assert ev.run.layout["vector_class"] == "CartPoleVectorEnv"
    assert ev.run.layout["sub_envs"] is False
    episodes = ev.episodes()
    assert episodes.num_rows >= 3 and pc.all(pc.equal(ev.steps()["reward"], 1.0)).as_py()
    findings = check([path]).findings
    (file_level,) = [f for f in findings if f.code == "not_replayable" and f.episode is None]
    assert "CartPoleVectorEnv has no sub-envs" in file_level.message
    result = replay([path])
    assert {e.status for e in result.episodes} == {"not_replayable"}
    assert "no sub-envs" in (result.episodes[0].reason or "")


@pytest.mark.parametrize("made", ["make_vec", "class"])
def test_a_vector_entry_point_envs_own_step_limit_is_recorded(tmp_path: Path, made: str) -> None:
    """CartPoleVectorEnv truncates each row at its own max_episode_steps (no TimeLimit): the
    file says that limit and its truncations are time_limit; still no sub-env to replay in."""
    from gymnasium.envs.classic_control.cartpole import CartPoleVectorEnv

    path = tmp_path / "own.mcap"
    envs = (
        gym.make_vec(
            "CartPole-v1", 4, vectorization_mode="vector_entry_point", max_episode_steps=12
        )
        if made == "make_vec"
        else CartPoleVectorEnv(num_envs=4, max_episode_steps=12)
    )
    with RecordVectorEvidence(envs, path) as rec:
        rec.reset(seed=0)
        for t in range(26):
            rec.step(np.full(4, t % 2, np.int64))
    ev = open_evidence(path)
    if made == "make_vec":
        assert ev.run.env_spec["max_episode_steps"] == 12
    ended = [e for e in ev.episodes().to_pylist() if e["outcome"] != "incomplete"]
    assert [(e["length"], e["outcome"], e["truncation_reason"]) for e in ended] == [
        (12, "truncated", "time_limit")
    ] * 8
    result = replay([path])
    assert {e.reason for e in result.episodes} == {
        "CartPoleVectorEnv has no sub-envs (a vector_entry_point env): its episodes cannot be "
        "replayed on their own"
    }


class _Scored(gym.Env[np.ndarray, np.int64]):
    """Pays named terms; succeeds after 3 steps when the action is 1, fails when it is 0."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        super().reset(seed=seed)
        self.t = 0
        return self.np_random.uniform(-1, 1, 2).astype(np.float32), {}

    def step(self, action: Any) -> Any:
        self.t += 1
        done = self.t >= 3
        info: dict[str, Any] = {"reward_terms": {"alive": 1.0, "bonus": 0.5 * int(action)}}
        if done:
            info["success" if action else "failure"] = True if action else "fell"
        obs = self.np_random.uniform(-1, 1, 2).astype(np.float32)
        return obs, 1.0 + 0.5 * int(action), done, False, info


def test_terms_and_endings_come_from_each_sub_envs_info(tmp_path: Path) -> None:
    path = tmp_path / "scored.mcap"
    for mode in ("NextStep", "SameStep"):
        envs = SyncVectorEnv([_Scored, _Scored], autoreset_mode=mode)
        with RecordVectorEvidence(envs, path, overwrite=True, ending_rules=None) as rec:
            rec.reset(seed=1)
            for _ in range(8):
                rec.step(np.array([1, 0]))
        episodes = open_evidence(path).episodes().to_pylist()
        ended = [e for e in episodes if e["outcome"] != "incomplete"]
        assert {(e["env_index"], e["outcome"], e["failure_label"]) for e in ended} == {
            (0, "success", None),
            (1, "failure", "fell"),
        }, mode
        for e in ended:
            bonus = 1.5 if e["env_index"] == 0 else 0.0
            assert dict(e["term_totals"]) == {"alive": 3.0, "bonus": bonus}
        # an unregistered env has no spec to rebuild it from; nothing else is wrong
        assert {f.code for f in check([path]).findings} <= {
            "incomplete_episode",
            "missing_env_spec",
        }


def test_env_infos_picks_one_sub_envs_values() -> None:
    from episode_audit.record.vector.infos import env_infos as _env_infos

    infos = {
        "a": np.array([1.0, 2.0]),
        "_a": np.array([True, False]),
        "d": {"x": np.array([0, 7]), "_x": np.array([False, True])},
        "_d": np.array([False, True]),
    }
    assert _env_infos(infos, 2) == ([{"a": 1.0}, {"d": {"x": 7}}], None)
    # no masks (a vector env of one's own): present for every sub-env, and said so
    unmasked = {"s": np.array([True, False]), "t": {"u": [1, 2]}, "level": "hard", "_x": 5}
    subs, why = _env_infos(unmasked, 2)
    assert subs == [
        {"s": True, "t": {"u": 1}, "level": "hard", "_x": 5},
        {"s": False, "t": {"u": 2}, "level": "hard", "_x": 5},
    ]
    assert why is not None and why.startswith("info_unmasked: ")
    assert "s, t.u, level (the same for every sub-env), _x (the same" in why
    assert _env_infos([{"a": 1}, {}], 2) == ([{"a": 1}, {}], None)
    assert _env_infos("oops", 2) == (["oops", "oops"], None)


def test_a_nested_dict_without_masks_of_its_own_takes_its_keys_mask(tmp_path: Path) -> None:
    """Gymnasium's vector RecordEpisodeStatistics masks ``_episode``, not ``episode._r``: the
    inner keys were guesses (info_unmasked) and every sub-env got an ``episode`` entry."""
    from episode_audit.record.vector.infos import env_infos as _env_infos

    stats = {
        "episode": {"r": np.array([9.0, 0.0]), "l": np.array([9, 0]), "t": np.array([0.1, 0])},
        "_episode": np.array([True, False]),
    }
    assert _env_infos(stats, 2) == ([{"episode": {"r": 9.0, "l": 9, "t": 0.1}}, {}], None)
    path = tmp_path / "stats.mcap"
    venv = gym.make_vec("CartPole-v1", 2, vectorization_mode="sync")
    with RecordVectorEvidence(gym.wrappers.vector.RecordEpisodeStatistics(venv), path) as envs:
        envs.reset(seed=0)
        envs.action_space.seed(0)
        for _ in range(100):
            envs.step(envs.action_space.sample())
    codes = {f.code for f in check([path]).findings}
    assert not {c for c in codes if "info_unmasked" in c}, codes


def test_misuse_raises_and_bad_input_does_not(tmp_path: Path) -> None:
    envs = gym.make_vec("CartPole-v1", 2, vectorization_mode="sync")
    rec = RecordVectorEvidence(envs, tmp_path / "m.mcap")
    rec.reset(seed=0)
    rec.close()
    rec.close()  # twice is fine
    with pytest.raises(RecorderError, match="closed"):
        rec.step(np.zeros(2, dtype=np.int64))
    with pytest.raises(Exception, match="file exists"):
        RecordVectorEvidence(gym.make_vec("CartPole-v1", 2), tmp_path / "m.mcap")


def test_batched_rows_equal_the_row_by_row_ones(tmp_path: Path) -> None:
    """Steps without info are kept as whole batches; info_keys forces the per-row path."""
    tables = []
    for name, info_keys in (("batched", ()), ("rows", "all")):
        path = tmp_path / f"{name}.mcap"
        envs = gym.make_vec("CartPole-v1", N, vectorization_mode="sync")
        actions = _actions()[:700]
        with RecordVectorEvidence(envs, path, block_steps=50, info_keys=info_keys) as rec:
            rec.reset(seed=SEED)
            for t, action in enumerate(actions):
                rec.step(action)
                if t == 333:
                    rec.flush()
        ev = open_evidence(path)
        keep = ["episode", "step", "action", "observation", "reward", "terminated", "truncated"]
        tables.append(
            (
                ev.steps(columns=[*keep, "outcome", "label"]),
                ev.episodes().drop_columns(["start_time_ns", "end_time_ns"]),
                ev.resets().select(["episode", "env_index", "seed", "rng_state", "observation"]),
            )
        )
    (steps_a, eps_a, resets_a), (steps_b, eps_b, resets_b) = tables
    # the same rows (the reader's episode order follows the flushes, which differ)
    order = [("episode", "ascending"), ("step", "ascending")]
    assert steps_a.sort_by(order).equals(steps_b.sort_by(order))
    assert eps_a.equals(eps_b)
    assert resets_a.sort_by("episode").equals(resets_b.sort_by("episode"))
    # blocks of at most block_steps rows per sub-env
    assert (
        max(b.num_rows for b in open_evidence(tmp_path / "batched.mcap").scan() for b in b.steps)
        <= 50
    )


def _ending_infos_step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
    """Episodes of 3 to 6 steps; their last step's info says why (or has a reward term)."""
    obs = env.np_random.uniform(-1, 1, 2).astype(np.float32)
    length = 3 + int(env.np_random.integers(0, 4))
    if env.t < length:
        return obs, 1.0, False, False, {}
    kind = int(env.np_random.integers(0, 4))
    info: dict[str, Any] = [
        {},
        {"failure": "fell"},
        {"is_success": True},
        {"reward_bonus": 0.5, "other": 1},
    ][kind]
    return obs, 1.0 + (0.5 if kind == 3 else 0.0), kind != 0, kind == 0, info


@pytest.mark.parametrize("monitor", [False, True], ids=["bare", "final info kept"])
def test_same_step_endings_are_batched_as_the_row_by_row_path_records_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, monitor: bool
) -> None:
    """SAME_STEP endings are batched (the final obs, the final info's reward terms, the ending
    by the rules, then the reset row): the same rows as the per-sub-env path."""
    from episode_audit.record.vector.modes import SameStep

    def make() -> gym.Env[Any, Any]:
        env: gym.Env[Any, Any] = ScriptedEnv(_ending_infos_step)
        if monitor:
            env = gym.wrappers.RecordEpisodeStatistics(env)  # (an "episode" in the final info)
        return ResetRngInfo(env)

    taken = Counter[str]()
    record_ending = SameStep.record_ending

    def counted(self: SameStep, *args: Any) -> None:
        taken["row by row"] += 1
        record_ending(self, *args)

    monkeypatch.setattr(SameStep, "record_ending", counted)
    tables = []
    for name, info_keys in (("batched", ()), ("rows", "all")):
        taken.clear()
        path = tmp_path / f"{name}.mcap"
        envs = SyncVectorEnv([make] * N, autoreset_mode=AutoresetMode.SAME_STEP)
        with RecordVectorEvidence(envs, path, block_steps=40, info_keys=info_keys) as rec:
            rec.reset(seed=SEED)
            for t in range(300):
                rec.step(np.zeros(N, dtype=np.int64))
                if t == 150:
                    rec.flush()
        ev = open_evidence(path)
        keep = ["episode", "step", "observation", "reward", "terms", "terminated", "truncated"]
        tables.append(
            (
                ev.steps(columns=[*keep, "outcome", "label"]),
                ev.episodes().drop_columns(["start_time_ns", "end_time_ns"]),
                ev.resets().select(["episode", "env_index", "seed", "rng_state", "observation"]),
                taken["row by row"],
            )
        )
    (steps_a, eps_a, resets_a, slow_a), (steps_b, eps_b, resets_b, slow_b) = tables
    # the batched run took no ending the row-by-row way, the endings with a term included
    assert slow_a == 0 < slow_b == eps_b.num_rows - N  # (the last N episodes did not end)
    assert any(dict(t).get("reward_bonus") for t in eps_a.column("term_totals").to_pylist())
    assert set(pc.unique(eps_a.column("failure_label")).to_pylist()) >= {"fell", "unlabeled"}
    assert pc.sum(pc.equal(eps_a.column("outcome"), "success")).as_py() > 0
    order = [("episode", "ascending"), ("step", "ascending")]
    assert steps_a.sort_by(order).equals(steps_b.sort_by(order))
    assert eps_a.equals(eps_b)
    assert resets_a.sort_by("episode").equals(resets_b.sort_by("episode"))


def _normalized_cartpole() -> gym.Env[Any, Any]:
    return gym.wrappers.NormalizeObservation(gym.make("CartPole-v1"))


@pytest.mark.parametrize("mode", ["NextStep", "SameStep"])
def test_the_recorder_returns_what_the_vector_env_returns(tmp_path: Path, mode: str) -> None:
    """The ResetRngInfo the recorder installs (snapshotting NormalizeObservation, putting the RNG
    state of each autoreset) adds nothing to the infos the loop gets."""
    from gymnasium.utils.env_checker import check_env, data_equivalence

    def make() -> Any:
        return SyncVectorEnv([_normalized_cartpole] * 3, autoreset_mode=AutoresetMode(mode))

    bare = make()
    rec = RecordVectorEvidence(make(), tmp_path / f"{mode}.mcap")
    assert data_equivalence(bare.reset(seed=2), rec.reset(seed=2))
    assert data_equivalence(bare.reset(), rec.reset())  # (unseeded: an RNG state too)
    for action in np.random.default_rng(1).integers(0, 2, size=(120, 3)):
        got, want = rec.step(action), bare.step(action)
        assert data_equivalence(got, want)
    rec.close()
    bare.close()
    resets = open_evidence(tmp_path / f"{mode}.mcap").resets().to_pylist()
    assert len(resets) > 9  # (the recorder still read the keys: states and snapshots)
    assert all(r["seed"] is not None or r["rng_state"] is not None for r in resets)
    assert all(r["state"] is not None for r in resets)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(ResetRngInfo(gym.make("CartPole-v1")), skip_render_check=True)


@pytest.mark.parametrize("mode", ["NextStep", "SameStep"])
def test_the_recorder_over_dict_info_to_list_returns_what_it_returns(
    tmp_path: Path, mode: str
) -> None:
    """Infos as a list of dicts: those of the sub-envs the recorder gave a ResetRngInfo lose its
    keys too."""
    from gymnasium.utils.env_checker import data_equivalence
    from gymnasium.wrappers.vector import DictInfoToList

    def make() -> Any:
        envs = SyncVectorEnv([_normalized_cartpole] * 3, autoreset_mode=AutoresetMode(mode))
        return DictInfoToList(envs)

    bare = make()
    rec = RecordVectorEvidence(make(), tmp_path / f"{mode}.mcap")
    assert data_equivalence(bare.reset(seed=2), rec.reset(seed=2))
    assert data_equivalence(bare.reset(), rec.reset())  # (unseeded: an RNG state too)
    for action in np.random.default_rng(1).integers(0, 2, size=(120, 3)):
        assert data_equivalence(rec.step(action), bare.step(action))
    rec.close()
    bare.close()
    resets = open_evidence(tmp_path / f"{mode}.mcap").resets().to_pylist()
    assert len(resets) > 9  # (the recorder still read the keys: states and snapshots)
    assert all(r["seed"] is not None or r["rng_state"] is not None for r in resets)


def test_a_reset_rng_info_of_one_s_own_keeps_its_keys_in_the_infos(tmp_path: Path) -> None:
    """Sub-env 0 has the user's ResetRngInfo, the others the recorder's: only sub-env 0's keys
    reach the loop, as they do without the recorder."""
    thunks = [lambda: ResetRngInfo(gym.make("CartPole-v1"))] + [lambda: gym.make("CartPole-v1")] * 2
    bare = SyncVectorEnv(thunks, autoreset_mode=AutoresetMode.SAME_STEP)
    rec = RecordVectorEvidence(
        SyncVectorEnv(thunks, autoreset_mode=AutoresetMode.SAME_STEP), tmp_path / "own.mcap"
    )
    rec.reset(seed=2)
    bare.reset(seed=2)
    seen = 0
    for action in np.random.default_rng(1).integers(0, 2, size=(200, 3)):
        got, want = rec.step(action)[4], bare.step(action)[4]
        assert got.keys() == want.keys()
        if "_episode_audit.rng_state" in want:
            seen += 1
            assert got["_episode_audit.rng_state"].tolist() == (
                want["_episode_audit.rng_state"].tolist()
            )
            assert got["episode_audit.rng_state"].tolist() == (
                want["episode_audit.rng_state"].tolist()
            )
    rec.close()
    bare.close()
    assert seen > 0


def test_reset_rng_info_hands_the_recorder_its_state_unparsed() -> None:
    """The state a sub-env's ResetRngInfo wrote into a reset info reaches the recorder as the
    dict it was written from (that very text only, once); any other text is parsed."""
    envs = SyncVectorEnv([lambda: gym.make("CartPole-v1")] * 2)
    rng = SubEnvRng(envs, None)
    rng.install_wrappers()
    envs.reset(seed=3)
    wrapper = envs.envs[1]
    assert isinstance(wrapper, ResetRngInfo)
    _, info = wrapper.reset()
    text = info["episode_audit.rng_state"]
    copy = "".join(list(text))
    assert copy == text and copy is not text
    parsed = rng.from_info({"episode_audit.rng_state": copy}, 1)
    assert parsed == json.loads(text) and parsed is not None
    assert rng.from_info(info, 0) == parsed  # another sub-env's wrapper did not write it
    issued = wrapper._issued
    assert issued is not None and issued[0] is text and issued[1] == parsed
    assert rng.from_info(info, 1) is issued[1]  # the wrapper's own dict, not parsed
    assert wrapper._issued_state(text) is None  # taken once
    assert rng.from_info(info, 1) == parsed  # then parsed


class _Breaks(gym.Env[np.ndarray, np.int64]):
    """Raises on its 5th step."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(2, np.float32), {}

    def step(self, action: Any) -> Any:
        self.t += 1
        if self.t == 5:
            raise RuntimeError("motor on fire")
        return np.zeros(2, np.float32), 1.0, False, False, {}


def test_an_env_error_ends_the_open_episodes_and_reraises(tmp_path: Path) -> None:
    path = tmp_path / "broken.mcap"
    rec = RecordVectorEvidence(SyncVectorEnv([_Breaks, _Breaks]), path)
    rec.reset(seed=[4, None])
    for _ in range(4):
        rec.step(np.zeros(2, dtype=np.int64))
    with pytest.raises(RuntimeError, match="motor on fire"):
        rec.step(np.zeros(2, dtype=np.int64))
    rec.close()
    episodes = open_evidence(path).episodes().to_pylist()
    assert [(e["env_index"], e["seed"], e["outcome"], e["length"]) for e in episodes] == [
        (0, 4, "error", 4),
        (1, None, "error", 4),
    ]
    assert episodes[1]["rng_state"] is not None  # seed list: sub-env 1 reset unseeded
    assert episodes[0]["error_message"] == "motor on fire"


# ---------------------------------------------------------------- misbehaving vector envs


class _Quiet(gym.Env[np.ndarray, np.int64]):
    """No info; terminates on its 3rd step (never, with ``ends=False``)."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
    action_space = gym.spaces.Discrete(2)

    def __init__(self, ends: bool = True) -> None:
        self.t = 0
        self.ends = ends

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        super().reset(seed=seed)
        self.t = 0
        return self.np_random.uniform(-1, 1, 2).astype(np.float32), {}

    def step(self, action: Any) -> Any:
        self.t += 1
        obs = self.np_random.uniform(-1, 1, 2).astype(np.float32)
        return obs, 1.0, self.ends and self.t >= 3, False, {}


class _SetInfos(gym.vector.VectorWrapper):
    """Hands out ``infos`` in place of the vector env's infos."""

    def __init__(self, env: Any, infos: Any) -> None:
        super().__init__(env)
        self.infos = infos

    def reset(self, **kwargs: Any) -> Any:
        obs, _ = self.env.reset(**kwargs)
        return obs, self.infos

    def step(self, actions: Any) -> Any:
        *result, _ = self.env.step(actions)
        return (*result, self.infos)


def _codes(path: Path) -> set[str]:
    return {f.code for f in check([path]).findings}


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("mode", ["NextStep", "SameStep"])
def test_infos_as_a_list_of_dicts_are_read_per_sub_env(
    tmp_path: Path, kind: str, mode: str
) -> None:
    """gymnasium's DictInfoToList between the recorder and the vector env: the same episodes."""
    from gymnasium.vector import AsyncVectorEnv
    from gymnasium.wrappers.vector import DictInfoToList

    path = tmp_path / "list.mcap"
    make = SyncVectorEnv if kind == "sync" else AsyncVectorEnv
    envs = DictInfoToList(make([_Scored, _Scored], autoreset_mode=mode))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no recorder trouble
        with RecordVectorEvidence(envs, path, ending_rules=None) as rec:
            rec.reset(seed=1)
            for _ in range(8):
                rec.step(np.array([1, 0]))
    ev = open_evidence(path)
    ended = [e for e in ev.episodes().to_pylist() if e["outcome"] != "incomplete"]
    assert sorted((e["env_index"], e["outcome"], e["failure_label"]) for e in ended) == [
        (0, "success", None),
        (0, "success", None),
        (1, "failure", "fell"),
        (1, "failure", "fell"),
    ]
    for e in ended:
        assert dict(e["term_totals"]) == {"alive": 3.0, "bonus": 1.5 if e["env_index"] == 0 else 0}
    assert ev.steps().num_rows == (12 if mode == "NextStep" else 16)
    # (Async SAME_STEP without ResetRngInfo: autoreset episodes without RNG states)
    allowed = {"incomplete_episode", "missing_env_spec"}
    allowed |= {"not_replayable", "recorder_note:rng_state_unavailable"}
    assert _codes(path) <= allowed


@pytest.mark.parametrize("infos", [None, "oops", [{}], ({}, 3)], ids=repr)
def test_infos_neither_dict_nor_list_of_dicts_are_noted_and_the_rows_kept(
    tmp_path: Path, infos: Any
) -> None:
    path = tmp_path / "odd.mcap"
    envs = _SetInfos(SyncVectorEnv([_Quiet, _Quiet]), infos)
    with pytest.warns(UserWarning, match="the recorder wrapped the vector wrapper _SetInfos"):
        rec = RecordVectorEvidence(envs, path)
    with rec:
        rec.reset(seed=1)
        for _ in range(4):  # 3 steps, then the autoreset
            rec.step(np.zeros(2, dtype=np.int64))
    ev = open_evidence(path)
    episodes = ev.episodes().to_pylist()
    assert sorted((e["env_index"], e["outcome"], e["length"]) for e in episodes) == [
        (0, "failure", 3),
        (0, "incomplete", 0),
        (1, "failure", 3),
        (1, "incomplete", 0),
    ]
    assert ev.steps().num_rows == 6
    env_index = {e["episode"]: e["env_index"] for e in episodes}
    noted = {(env_index[ep], code) for ep, code in _noted(path)}
    if infos == ({}, 3):  # sub-env 0's info is fine; sub-env 1's is an int
        assert noted == {(1, "info_not_dict")}
    else:
        assert noted == {(0, "info_not_dict"), (1, "info_not_dict")}
    check([path])
    replay([path])


def _noted(path: Path) -> Counter[tuple[int, str]]:
    """(episode, note code) of every note on a step or reset row of the file."""
    ev = open_evidence(path)
    rows = [*ev.steps(columns=["episode", "notes"]).to_pylist(), *ev.resets().to_pylist()]
    return Counter(
        (r["episode"], n.split(":")[0]) for r in rows if r["notes"] for n in json.loads(r["notes"])
    )


class _TwoEnvVec(gym.vector.VectorEnv):  # type: ignore[type-arg]
    """A vector env of its own (no sub-envs) of two sub-envs: zero observations, counting steps."""

    def __init__(self) -> None:
        from gymnasium.vector.utils import batch_space

        self.num_envs = 2
        self.single_observation_space = gym.spaces.Box(-1, 1, (2,), np.float32)
        self.single_action_space = gym.spaces.Discrete(2)
        self.observation_space = batch_space(self.single_observation_space, 2)
        self.action_space = batch_space(self.single_action_space, 2)
        self.t = 0

    def reset(self, *, seed: Any = None, options: Any = None) -> Any:
        self.t = 0
        return np.zeros((2, 2), np.float32), {}


class _ListVec(_TwoEnvVec):
    """Results as Python lists; sub-env 1's reward is ``bad`` on the 3rd step, which ends both
    episodes."""

    metadata: dict[str, Any] = {"autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, bad: Any) -> None:
        super().__init__()
        self.bad = bad

    def step(self, actions: Any) -> Any:
        self.t += 1
        rewards: list[Any] = [1.0, self.bad if self.t == 3 else 1.0]
        done = self.t == 3
        self.t %= 4  # NEXT_STEP: the 4th step is the autoreset
        return np.zeros((2, 2), np.float32), rewards, [done, done], [False, False], {}


@pytest.mark.parametrize("bad", ["abc", "1.5", [1.0]], ids=repr)
def test_a_reward_that_is_not_a_number_is_noted_and_the_step_kept(tmp_path: Path, bad: Any) -> None:
    """As the single-env recorder: NaN and ``reward_not_numeric``; close() never raises."""
    path = tmp_path / "rewards.mcap"
    rec = RecordVectorEvidence(_ListVec(bad), path, flush_every_s=0.001)
    rec.reset(seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no recorder trouble
        for _ in range(8):
            rec.step(np.zeros(2, np.int64))
        rec.close()
    ev = open_evidence(path)
    assert ev.finished
    episodes = ev.episodes().to_pylist()
    assert [(e["env_index"], e["outcome"], e["length"]) for e in episodes][:4] == [
        (0, "failure", 3),
        (1, "failure", 3),
        (0, "failure", 3),
        (1, "failure", 3),
    ]
    rewards = ev.steps(columns=["episode", "step", "reward"]).to_pylist()
    assert len(rewards) == 12
    nan = [(r["episode"], r["step"]) for r in rewards if r["reward"] != r["reward"]]
    assert nan == [(1, 2), (3, 2)]
    noted = {k for k in _noted(path) if k[1] != "rng_state_unavailable"}  # (no sub-envs)
    assert noted == {(1, "reward_not_numeric"), (3, "reward_not_numeric")}
    assert "length_mismatch" not in _codes(path)


@pytest.mark.parametrize("options", [["hard"], ("hard", 2), "hard"], ids=repr)
def test_reset_options_that_are_not_a_dict_are_passed_on_and_recorded(
    tmp_path: Path, options: Any
) -> None:
    from episode_audit import RecordEvidence

    path = tmp_path / "options.mcap"
    with RecordVectorEvidence(SyncVectorEnv([_Quiet, _Quiet]), path) as rec:
        rec.reset(seed=0, options=options)
        rec.step(np.zeros(2, np.int64))
    single = tmp_path / "single.mcap"
    with RecordEvidence(_Quiet(), single) as env:
        env.reset(seed=0, options=options)
    want = open_evidence(single).episodes().to_pylist()[0]["options"]
    assert [e["options"] for e in open_evidence(path).episodes().to_pylist()] == [want, want]


@pytest.mark.parametrize("kind", KINDS)
def test_steps_before_reset_are_noted_like_the_single_env_recorder(
    tmp_path: Path, kind: str
) -> None:
    from gymnasium.vector import AsyncVectorEnv

    path = tmp_path / "early.mcap"
    make = SyncVectorEnv if kind == "sync" else AsyncVectorEnv
    envs = make([lambda: _Quiet(ends=False)] * 2)
    with RecordVectorEvidence(envs, path) as rec:
        for _ in range(2):
            rec.step(np.zeros(2, np.int64))
        rec.reset(seed=0)
        for _ in range(2):
            rec.step(np.zeros(2, np.int64))
    ev = open_evidence(path)
    assert -1 not in ev.steps()["episode"].to_pylist()
    episodes = ev.episodes().to_pylist()
    assert [(e["env_index"], e["length"], e["seed"]) for e in episodes] == [
        (0, 2, None),
        (1, 2, None),
        (0, 2, 0),
        (1, 2, 1),
    ]
    assert _noted(path) == Counter({(0, "stepped_before_reset"): 1, (1, "stepped_before_reset"): 1})
    assert "length_mismatch" not in _codes(path)


def test_steps_after_an_episode_ended_are_noted_like_the_single_env_recorder(
    tmp_path: Path,
) -> None:
    """The vector env stepped on (without a reset) after a sub-env raised."""
    path = tmp_path / "after-error.mcap"
    rec = RecordVectorEvidence(SyncVectorEnv([_Breaks, _Breaks]), path)
    rec.reset(seed=0)
    raised = 0
    for _ in range(7):  # sub-env 0 raises on the 5th step, sub-env 1 on the 6th
        try:
            rec.step(np.zeros(2, np.int64))
        except RuntimeError:
            raised += 1
    rec.close()
    assert raised == 2
    episodes = open_evidence(path).episodes().to_pylist()
    assert [(e["outcome"], e["length"]) for e in episodes] == [("error", 4)] * 2
    assert _noted(path) == Counter({(0, "step_after_end"): 1, (1, "step_after_end"): 1})
    assert "length_mismatch" not in _codes(path)


@pytest.mark.parametrize("mode", ["NextStep", "SameStep", "Disabled"])
def test_a_time_limit_without_a_spec_is_found_on_each_sub_env(tmp_path: Path, mode: str) -> None:
    from gymnasium.wrappers import TimeLimit

    path = tmp_path / "limit.mcap"
    envs = SyncVectorEnv([lambda: TimeLimit(_Quiet(ends=False), 2)] * 2, autoreset_mode=mode)
    with RecordVectorEvidence(envs, path) as rec:
        rec.reset(seed=0)
        for _ in range(3):
            _, _, term, trunc, _ = rec.step(np.zeros(2, np.int64))
            if mode == "Disabled" and (term | trunc).any():
                rec.reset(options={"reset_mask": term | trunc})
    ended = [e for e in open_evidence(path).episodes().to_pylist() if e["outcome"] != "incomplete"]
    assert [(e["outcome"], e["truncation_reason"]) for e in ended] == [
        ("truncated", "time_limit")
    ] * 2


@pytest.mark.parametrize("mode", ["NextStep", "Disabled"])
@pytest.mark.parametrize(("limit", "length"), [(30, 30), (60, 50), (None, 50)])
def test_sub_env_time_limits_over_and_under_a_frame_skip_are_each_read(
    tmp_path: Path, mode: str, limit: int | None, length: int
) -> None:
    """The TimeLimit under MaxAndSkipObservation counts the env's steps (200: 50 steps), the
    one over it the sub-env's: the streams read them as the single-env recorder does."""
    path = tmp_path / "skip.mcap"
    envs = SyncVectorEnv([lambda: skipping_pendulum(limit)] * 2, autoreset_mode=mode)
    with RecordVectorEvidence(envs, path) as rec:
        rec.action_space.seed(0)
        rec.reset(seed=0)
        for _ in range(length):
            rec.step(rec.action_space.sample())
    ended = [e for e in open_evidence(path).episodes().to_pylist() if e["outcome"] != "incomplete"]
    assert [(e["length"], e["truncation_reason"]) for e in ended] == [(length, "time_limit")] * 2
    result = replay([path])
    assert [(e.status, e.steps) for e in result.episodes] == [("identical", length)] * 2


@pytest.mark.parametrize("kind", KINDS)
def test_reset_arguments_the_vector_env_rejects_change_no_episode(
    tmp_path: Path, kind: str
) -> None:
    from gymnasium.vector import AsyncVectorEnv

    path = tmp_path / "rejected.mcap"
    make = SyncVectorEnv if kind == "sync" else AsyncVectorEnv
    envs = make([lambda: _Quiet(ends=False)] * 2, autoreset_mode="Disabled")
    with RecordVectorEvidence(envs, path) as rec:
        rec.reset(seed=0)
        rec.step(np.zeros(2, np.int64))
        for seed, options in (
            ([1, 2, 3], None),
            (None, {"reset_mask": [True, False]}),
            (None, {"reset_mask": np.array([1, 0])}),
            (None, {"reset_mask": np.array([True])}),
        ):
            # (Gymnasium 1.3 asserts a seed list's length)
            with pytest.raises((ValueError, TypeError, AssertionError)):
                rec.reset(seed=seed, options=options)
        rec.step(np.zeros(2, np.int64))
    episodes = open_evidence(path).episodes().to_pylist()
    assert [(e["outcome"], e["length"], e["seed"]) for e in episodes] == [
        ("incomplete", 2, 0),
        ("incomplete", 2, 1),
    ]
    assert _codes(path) <= {"incomplete_episode", "missing_env_spec", "missing_terms"}


@pytest.mark.parametrize("kind", KINDS)
def test_a_time_limit_without_a_spec_is_found_on_async_sub_envs_too(
    tmp_path: Path, kind: str
) -> None:
    """An AsyncVectorEnv's workers are asked only when every one has a TimeLimit: a worker asked
    for an attribute its env lacks raises, and dies (mixed sub-envs: the limit is unknown)."""
    from gymnasium.vector import AsyncVectorEnv
    from gymnasium.wrappers import TimeLimit

    def limited() -> Any:
        return TimeLimit(_Quiet(ends=False), 2)

    def unlimited() -> Any:
        return _Quiet(ends=False)

    make = SyncVectorEnv if kind == "sync" else AsyncVectorEnv
    for fns, want in (
        ([limited, limited], [(0, "time_limit"), (1, "time_limit")]),
        ([limited, unlimited], [(0, "time_limit" if kind == "sync" else "external")]),
    ):
        path = tmp_path / "limit.mcap"
        with RecordVectorEvidence(make(fns), path, overwrite=True) as rec:
            rec.reset(seed=0)
            for _ in range(4):  # 2 steps, the autoreset, a step (every worker still alive)
                rec.step(np.zeros(2, np.int64))
        episodes = open_evidence(path).episodes().to_pylist()
        ended = [e for e in episodes if e["outcome"] != "incomplete"]
        assert [(e["env_index"], e["truncation_reason"]) for e in ended] == want


def _clipped_cartpole() -> Any:
    """CleanRL's continuous-control stack in small: a lambda in a wrapper's kwargs, which the
    sub-env's spec keeps and which does not pickle."""
    env = gym.make("CartPole-v1")
    return gym.wrappers.TransformObservation(
        env, lambda obs: np.clip(obs, -10, 10), env.observation_space
    )


def _rng_clipped_cartpole() -> Any:
    return ResetRngInfo(_clipped_cartpole())


@pytest.mark.parametrize("make", [_clipped_cartpole, _rng_clipped_cartpole])
def test_a_spec_that_does_not_pickle_leaves_async_workers_alive(tmp_path: Path, make: Any) -> None:
    """A worker asked for such a spec fails to send it and ends: the recorder reads it off a
    sub-env built in this process instead, as AsyncVectorEnv's constructor builds one."""
    from gymnasium.vector import AsyncVectorEnv

    path = tmp_path / "async.mcap"
    with RecordVectorEvidence(AsyncVectorEnv([make] * 2), path) as rec:
        rec.reset(seed=1)
        for _ in range(20):
            rec.step(np.ones(2, np.int64))
    spec = open_evidence(path).run.env_spec
    assert isinstance(spec, dict) and spec["id"] == "CartPole-v1"
    assert {e["env_index"] for e in open_evidence(path).episodes().to_pylist()} == {0, 1}


# (AsyncVectorEnv forks; Python 3.12+ warns when a thread is running then, e.g. ALE's)
@pytest.mark.filterwarnings("ignore:This process .* is multi-threaded:DeprecationWarning")
def test_an_env_s_own_state_in_async_workers_without_reset_rng_info_is_warned_of(
    tmp_path: Path,
) -> None:
    """ALE's emulator state in workers that no ResetRngInfo snapshots: the episodes an
    unseeded reset began cannot be replayed, and the recorder and check say so."""
    from gymnasium.vector import AsyncVectorEnv

    path = tmp_path / "pong.mcap"
    envs = AsyncVectorEnv([short_pong] * 2)
    with pytest.warns(UserWarning, match=UNSAVED_WARNING):
        rec = RecordVectorEvidence(envs, path)
    with rec:
        rec.reset(seed=3)
        rec.step(np.array([0, 1]))
        rec.reset()
        rec.step(np.array([0, 1]))
    assert_unseeded_episodes_are_not_replayable(path)


class _Duck:
    """A sub-env with an env's methods and spaces, not a ``gymnasium.Env`` (as one written for
    the old ``gym``): SyncVectorEnv steps it."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = gym.spaces.Discrete(2)
    metadata: dict[str, Any] = {}
    render_mode = None

    def reset(self, *, seed: int | None = None, options: Any = None) -> Any:
        return np.zeros(1, np.float32), {}

    def step(self, action: Any) -> Any:
        return np.zeros(1, np.float32), 0.0, False, False, {}

    def close(self) -> None:
        pass


def test_sub_envs_that_are_not_gymnasium_envs_are_refused_in_one_line(tmp_path: Path) -> None:
    envs = SyncVectorEnv([_Duck, _Duck])
    envs.reset(seed=0)
    with pytest.raises(
        ConfigurationError, match=r"^RecordVectorEvidence: sub-env 0 is not a gymnasium.Env, "
    ):
        RecordVectorEvidence(envs, tmp_path / "duck.mcap")
    assert not (tmp_path / "duck.mcap").exists()


class _Exclusive(gym.Wrapper[Any, Any, Any, Any]):
    """Holds an exclusive lock while alive, as an env holding a device or a licence does: a
    second copy built while the first lives fails (or, with a blocking lock, waits forever).
    Each copy writes the id of the process that built it to ``lock + ".pids"``."""

    def __init__(self, env: gym.Env[Any, Any], lock: str) -> None:
        import fcntl

        super().__init__(env)
        with open(lock + ".pids", "a") as pids:
            pids.write(f"{os.getpid()}\n")
        self._held = open(lock, "w")  # noqa: SIM115 (held until close)
        try:
            fcntl.flock(self._held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._held.close()
            raise

    def close(self) -> None:
        self._held.close()
        super().close()


def _exclusive(index: int, folder: str, outer: bool) -> Any:
    env = _Exclusive(gym.make("CartPole-v1"), f"{folder}/{index}.lock")
    return ResetRngInfo(env) if outer else env


def _exclusive_no_spec(index: int, folder: str) -> Any:
    """Without a spec (not made by gym.make), ResetRngInfo outermost."""
    from gymnasium.envs.classic_control import CartPoleEnv

    lock = f"{folder}/{index}.lock"
    return ResetRngInfo(_Exclusive(gym.wrappers.TimeLimit(CartPoleEnv(), 50), lock))


@pytest.mark.parametrize("kind", ["plain", "reset_rng_info", "no_spec"])
def test_an_async_sub_env_that_sends_its_spec_is_not_built_here(tmp_path: Path, kind: str) -> None:
    """With ResetRngInfo outermost its worker is asked for the spec; a copy built here would
    fail on the lock. Without it (``plain``) the worker is not asked (its spec might not
    pickle): the copy built here fails, and the spec is unknown."""
    from functools import partial

    from gymnasium.vector import AsyncVectorEnv

    folder = str(tmp_path)
    fns = [
        partial(_exclusive_no_spec, i, folder)
        if kind == "no_spec"
        else partial(_exclusive, i, folder, kind == "reset_rng_info")
        for i in range(2)
    ]
    path = tmp_path / "async.mcap"
    with RecordVectorEvidence(AsyncVectorEnv(fns), path) as rec:
        rec.reset(seed=1)
        rec.step(np.ones(2, np.int64))
    built_here = (tmp_path / "0.lock.pids").read_text().split().count(str(os.getpid()))
    # (AsyncVectorEnv's own, for its spaces, closed before its workers; plain: the recorder's)
    assert built_here == (2 if kind == "plain" else 1)
    spec = open_evidence(path).run.env_spec
    assert (spec or {}).get("id") == ("CartPole-v1" if kind == "reset_rng_info" else None)


# ---------------------------------------------------------------- info without masks


class _NoMaskVec(_TwoEnvVec):
    """Its info has values but no ``_key`` masks (Gymnasium's vector envs add them; one's own
    may not): reward terms on every step; on the 3rd, which ends both episodes, success for
    sub-env 0 and a failure label for sub-env 1."""

    metadata: dict[str, Any] = {"autoreset_mode": AutoresetMode.NEXT_STEP}

    def step(self, actions: Any) -> Any:
        self.t += 1
        done = self.t == 3
        info: dict[str, Any] = {"reward_terms": {"alive": np.ones(2), "bonus": [0.5, 0.0]}}
        if done:
            info["success"] = np.array([True, False])
            info["failure"] = [None, "fell"]
        self.t %= 4  # NEXT_STEP: the 4th step is the autoreset
        return np.zeros((2, 2), np.float32), np.array([1.5, 1.0]), np.full(2, done), [0, 0], info


def test_info_without_masks_is_read_for_every_sub_env_and_noted(tmp_path: Path) -> None:
    path = tmp_path / "nomask.mcap"
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no recorder trouble
        with RecordVectorEvidence(_NoMaskVec(), path, ending_rules=None) as rec:
            rec.reset(seed=0)
            for _ in range(4):
                rec.step(np.zeros(2, np.int64))
    episodes = open_evidence(path).episodes().to_pylist()
    ended = [e for e in episodes if e["outcome"] != "incomplete"]
    assert [(e["env_index"], e["outcome"], e["failure_label"]) for e in ended] == [
        (0, "success", None),
        (1, "failure", "fell"),
    ]
    assert [dict(e["term_totals"]) for e in ended] == [
        {"alive": 3.0, "bonus": 1.5},
        {"alive": 3.0, "bonus": 0.0},
    ]
    # every row read from such an info says so: 3 steps each, then the autoresets' reset rows
    noted = {k: v for k, v in _noted(path).items() if k[1] != "rng_state_unavailable"}
    assert noted == {
        (0, "info_unmasked"): 3,
        (1, "info_unmasked"): 3,
        (2, "info_unmasked"): 1,
        (3, "info_unmasked"): 1,
    }
    findings = check([path]).findings
    (why,) = {f.message.split(": ", 1)[1] for f in findings if f.code.endswith("info_unmasked")}
    assert "'_<key>' mask" in why and "reward_terms.alive, reward_terms.bonus" in why
    assert not {"missing_terms", "unlabeled_failure"} & {f.code for f in findings}


# ---------------------------------------------------------------- flags that are not bools


class _FlagVec(_TwoEnvVec):
    """``terminated`` on its 2nd step is ``flags`` as given."""

    metadata: dict[str, Any] = {"autoreset_mode": AutoresetMode.DISABLED}

    def __init__(self, flags: Any) -> None:
        super().__init__()
        self.flags = flags

    def step(self, actions: Any) -> Any:
        self.t += 1
        term = self.flags if self.t == 2 else np.zeros(2, np.bool_)
        return np.zeros((2, 2), np.float32), np.ones(2), term, np.zeros(2, np.bool_), {}


class _FlagEnv(gym.Env[np.ndarray, np.int64]):
    """One sub-env of :class:`_FlagVec`: ``terminated`` on its 2nd step is ``flag``."""

    observation_space = gym.spaces.Box(-1, 1, (2,), np.float32)
    action_space = gym.spaces.Discrete(2)

    def __init__(self, flag: Any) -> None:
        self.flag = flag
        self.t = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        self.t = 0
        return np.zeros(2, np.float32), {}

    def step(self, action: Any) -> Any:
        self.t += 1
        return np.zeros(2, np.float32), 1.0, self.flag if self.t == 2 else False, False, {}


@pytest.mark.parametrize(
    "flags",
    [["False", False], np.array([1, 0]), np.array(["False", ""]), [np.array([1, 2]), True]],
    ids=["text-list", "int-array", "str-array", "no-truth-value"],
)
def test_flags_that_are_not_bools_are_noted_like_the_single_env_recorder(
    tmp_path: Path, flags: Any
) -> None:
    from episode_audit import RecordEvidence

    path = tmp_path / "flags.mcap"
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no recorder trouble
        with RecordVectorEvidence(_FlagVec(flags), path) as rec:
            rec.reset(seed=0)
            for _ in range(2):
                rec.step(np.zeros(2, np.int64))
    ev = open_evidence(path)
    episodes = ev.episodes().to_pylist()
    steps = ev.steps(columns=["episode", "step", "notes"]).to_pylist()
    for i in range(2):
        single = tmp_path / f"single-{i}.mcap"
        with RecordEvidence(_FlagEnv(list(flags)[i]), single) as env:
            env.reset(seed=0)
            for _ in range(2):
                env.step(0)
        want_ep = open_evidence(single).episodes().to_pylist()[0]
        (got_ep,) = [e for e in episodes if e["env_index"] == i]
        keys = ["outcome", "failure_label", "terminated", "length"]
        assert [got_ep[k] for k in keys] == [want_ep[k] for k in keys], i

        def codes(rows: list[dict[str, Any]]) -> list[tuple[int, list[str]]]:
            return [
                (r["step"], [n.split(":")[0] for n in json.loads(r["notes"])])
                for r in rows
                if r["notes"]
            ]

        want = codes(open_evidence(single).steps(columns=["step", "notes"]).to_pylist())
        got = codes([r for r in steps if r["episode"] == got_ep["episode"]])
        assert got == want, i
    assert any(n for n in _noted(path) if n[1] == "flags_not_bool")


# ---------------------------------------------------------------- an autoreset that raises


class _ResetBomb(gym.Env[np.ndarray, np.int64]):
    """Terminates on its ``length``-th step; a reset without a seed raises (kept in ``raised``)."""

    observation_space = gym.spaces.Box(-1, 1, (2,), np.float32)
    action_space = gym.spaces.Discrete(2)
    raised: list[BaseException] = []

    def __init__(self, length: int) -> None:
        self.length = length
        self.t = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        super().reset(seed=seed)
        if seed is None:
            self.np_random.uniform()  # the failed reset draws
            exc = ValueError("reset refused")
            _ResetBomb.raised.append(exc)
            raise exc
        self.t = 0
        return np.zeros(2, np.float32), {}

    def step(self, action: Any) -> Any:
        self.t += 1
        return np.zeros(2, np.float32), 1.0, self.t == self.length, False, {}


def _bombs(kind: str, mode: str) -> Any:
    from gymnasium.vector import AsyncVectorEnv

    make = SyncVectorEnv if kind == "sync" else AsyncVectorEnv
    return make([lambda: _ResetBomb(3), lambda: _ResetBomb(5)], autoreset_mode=mode)


@pytest.mark.parametrize(
    ("kind", "mode"), [("sync", "NextStep"), ("async", "NextStep"), ("sync", "SameStep")]
)
def test_an_autoreset_that_raises_is_a_failed_reset_after_the_true_ending(
    tmp_path: Path, kind: str, mode: str
) -> None:
    """As a single env's reset() that raised: an episode ended ``error`` during ``reset``; the
    episode before it keeps its ending (SAME_STEP: its last step, kept by ResetRngInfo); the
    loop gets the env's exception."""
    path = tmp_path / "bomb.mcap"
    rec = RecordVectorEvidence(_bombs(kind, mode), path)
    rec.reset(seed=0)
    _ResetBomb.raised.clear()
    steps = 4 if mode == "NextStep" else 3  # sub-env 0 ends on step 3 and resets on step 4 / 3
    for _ in range(steps - 1):
        rec.step(np.zeros(2, np.int64))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # AsyncVectorEnv logs the worker's error
        with pytest.raises(ValueError, match="reset refused") as raised:
            rec.step(np.zeros(2, np.int64))
    if kind == "sync":
        assert raised.value is _ResetBomb.raised[-1]  # the env's own exception, untouched
    rec.close()
    episodes = open_evidence(path).episodes().to_pylist()
    got = [
        (e["env_index"], e["outcome"], e["length"], e["terminated"], e["error_during"])
        for e in episodes
    ]
    assert sorted(got) == [
        (0, "error", 0, False, "reset"),
        (0, "failure", 3, True, None),
        # the step raised while sub-env 1's episode ran (as any error in a vector step)
        (1, "error", steps - 1, False, "step"),
    ]
    (failed,) = [e for e in episodes if e["error_during"] == "reset"]
    assert failed["error_message"] == "reset refused" and failed["seed"] is None
    assert failed["rng_state"] is not None  # the state the failed reset started from
    assert "error_episode" in _codes(path)


def test_after_a_failed_autoreset_the_sync_vector_env_goes_on(tmp_path: Path) -> None:
    """NEXT_STEP SyncVectorEnv: the sub-env is still due for its autoreset; the loop resets."""
    path = tmp_path / "bomb-on.mcap"
    with RecordVectorEvidence(_bombs("sync", "NextStep"), path) as rec:
        rec.reset(seed=0)
        for _ in range(3):
            rec.step(np.zeros(2, np.int64))
        for _ in range(2):  # the autoreset is tried again, and raises again
            with pytest.raises(ValueError, match="reset refused"):
                rec.step(np.zeros(2, np.int64))
        rec.reset(seed=7)
        rec.step(np.zeros(2, np.int64))
    episodes = open_evidence(path).episodes().to_pylist()
    episodes.sort(key=lambda e: e["episode"])
    assert [(e["env_index"], e["outcome"], e["length"], e["seed"]) for e in episodes] == [
        (0, "failure", 3, 0),
        (1, "error", 3, 1),
        (0, "error", 0, None),
        (0, "error", 0, None),
        (0, "incomplete", 1, 7),
        (1, "incomplete", 1, 8),
    ]
    # each failed reset started from the state the sub-env was in then (the first one drew)
    first, second = [e["rng_state"] for e in episodes[2:4]]
    assert first is not None and second is not None and first != second


# sha-256 of every message (topic, log and publish time, data) of the file below (same numpy,
# pyarrow, zstd); change it only with a change that means to change what a vector recording
# writes
_GOLDEN_MESSAGES = "ea3c838ba6e1588a0bfb41896afc1024340b76111497b0e1ea717843f8057115"


def test_a_vector_recording_writes_the_same_messages_as_before(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Batched steps (int64 and int32 action batches mixed), a flush, a reset, full blocks."""
    ticks = itertools.count(1_000_000_000, 1_000)
    monkeypatch.setattr(time, "monotonic_ns", ticks.__next__)
    monkeypatch.setattr(time, "time_ns", lambda: 1_700_000_000_000_000_000)
    path = tmp_path / "golden.mcap"
    n = 4
    rng = np.random.default_rng(5)
    envs = gym.make_vec("CartPole-v1", n, vectorization_mode="sync")
    with RecordVectorEvidence(envs, path, block_steps=50, flush_every_s=1e9) as rec:
        rec.reset(seed=3)
        for t in range(700):
            action = rng.integers(0, 2, n)
            if 200 <= t < 230 or t % 97 == 0:
                action = action.astype(np.int32)
            rec.step(action)
            if t == 333:
                rec.flush()
            if t == 500:
                rec.reset(seed=9)
    digest = hashlib.sha256()
    with path.open("rb") as stream:
        for _, channel, message in make_reader(stream).iter_messages(log_time_order=False):
            digest.update(
                repr((channel.topic, message.log_time, message.publish_time, message.data)).encode()
            )
    assert digest.hexdigest() == _GOLDEN_MESSAGES, (
        "what a vector recording writes changed; if numpy, pyarrow, zstandard or gymnasium did "
        "(not this code), put the new digest in _GOLDEN_MESSAGES"
    )


def test_big_rows_are_batched_a_few_steps_at_a_time(tmp_path: Path) -> None:
    # 4 frames of 256 KB a vector step: 8 MB of batch buffers hold 8 steps, not BATCH_STEPS
    from episode_audit.record.vector.batch import BATCH_BYTES, BATCH_STEPS

    shape = (256, 256, 4)

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        return np.full(shape, env.t % 256, np.uint8), 1.0, env.t % 30 == 0, False, {}

    def make() -> ScriptedEnv:
        return ScriptedEnv(
            step_fn=step,
            reset_fn=lambda env: (np.zeros(shape, np.uint8), {}),
            observation_space=gym.spaces.Box(0, 255, shape, np.uint8),
            action_space=gym.spaces.Discrete(2),
        )

    path = tmp_path / "frames.mcap"
    held: set[tuple[int, int]] = set()
    with RecordVectorEvidence(SyncVectorEnv([make] * N), path) as rec:
        rec.reset(seed=0)
        for _ in range(100):
            rec.step(np.zeros(N, dtype=np.int64))
            batch = rec._steps._batch
            if batch.obs is not None:  # (None before the first batched step)
                held.add((batch.rows, batch.obs.nbytes))
    rows = BATCH_BYTES // (N * (shape[0] * shape[1] * shape[2] + 8))
    assert held == {(rows, rows * N * shape[0] * shape[1] * shape[2])}
    assert 1 < rows < BATCH_STEPS
    with open_evidence(path) as evidence:
        lengths = evidence.episodes().column("length").to_pylist()
    assert sum(lengths) + N * (100 // 31) == 100 * N  # (each autoreset step: a reset row)
    assert not [f for f in check([path]).findings if f.severity == "error"]


@pytest.mark.parametrize("mode", ["NEXT_STEP", "DISABLED"])
def test_steps_with_reward_terms_are_batched_as_sub_envs_would_record_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, mode: str
) -> None:
    """A MuJoCo vector env's steps (reward terms in every info) take the batched path, and the
    file holds what recording them sub-env by sub-env holds."""
    reading = InfoReading(monkeypatch, "step_terms")
    actions = np.random.default_rng(3).uniform(-1, 1, size=(170, 3, 2)).astype(np.float32)
    files, batched = {}, {}
    for kind in ("batched", "sub_envs"):
        env = gym.make_vec(
            "Reacher-v5",
            3,
            vectorization_mode="sync",
            vector_kwargs={"autoreset_mode": AutoresetMode[mode]},
        )
        files[kind] = tmp_path / f"{kind}.mcap"
        reading.run(declining=kind == "sub_envs")
        with RecordVectorEvidence(env, files[kind], flush_every_s=1e9) as rec:
            rec.reset(seed=1)
            for t, action in enumerate(actions):
                _, _, terminated, truncated, _ = rec.step(action)
                ended = np.asarray(terminated) | truncated
                if mode == "DISABLED" and ended.any():
                    rec.reset(options={"reset_mask": ended})
                elif t == 77:  # a reset of one sub-env mid-episode
                    rec.reset(seed=[7, None, None], options={"reset_mask": np.eye(3)[0] > 0})
        batched[kind] = sum(reading.taken)
    assert batched["batched"] > 150 and batched["sub_envs"] == 0
    assert len(reading.taken) > 150  # (the infos were looked at, and declined)
    assert messages(files["batched"]) == messages(files["sub_envs"])
    with open_evidence(files["batched"]) as evidence:
        totals = evidence.episodes().column("term_totals").to_pylist()
    assert len(totals) >= 9 and all(
        dict(t).keys() == {"reward_dist", "reward_ctrl"} for t in totals
    )


@pytest.mark.parametrize("make", [rng_locked_rng, rng_raising_rng])
def test_reset_rng_info_in_async_workers_answers_for_an_rng_they_cannot_send(
    tmp_path: Path, make: Any
) -> None:
    """A worker asked for an ``np_random`` that raises or does not pickle ends; the recorder
    asks the sub-env's ResetRngInfo instead, which answers JSON text (or why not)."""
    from gymnasium.vector import AsyncVectorEnv

    path = tmp_path / "async.mcap"
    with RecordVectorEvidence(AsyncVectorEnv([make] * 2), path) as rec:
        rec.reset(seed=1)
        for _ in range(3 * LIMIT + 1):
            rec.step(np.zeros(2, np.int64))
    autoreset = [e for e in open_evidence(path).episodes().to_pylist() if e["seed"] is None]
    assert len(autoreset) >= 4 and all(e["rng_state"] for e in autoreset)


def test_an_rng_state_reset_rng_info_cannot_read_in_a_worker_is_noted_with_why(
    tmp_path: Path,
) -> None:
    from gymnasium.vector import AsyncVectorEnv

    path = tmp_path / "async.mcap"
    with RecordVectorEvidence(AsyncVectorEnv([rng_sealed_rng] * 2), path) as rec:
        rec.reset(seed=1)
        for _ in range(LIMIT + 1):
            rec.step(np.zeros(2, np.int64))
    resets = open_evidence(path).resets().to_pylist()
    notes = [json.loads(r["notes"]) for r in resets if r["seed"] is None]
    assert len(notes) == 2 and all(
        n
        == [
            "rng_state_unavailable: its ResetRngInfo could not read it: reading its np_random "
            "raised RuntimeError"
        ]
        for n in notes
    ), notes


# ---------------------------------------------------------------- what workers are asked

_NOT_ASKED = (
    "rng_state_unavailable: its worker was not asked for its np_random, which could end it: "
    "{why}; wrap each sub-env in episode_audit.ResetRngInfo"
)


@pytest.mark.parametrize(
    ("make", "why"),
    [
        (lambda_kwarg, None),
        (raising_rng_made, "RaisingRng replaces Gymnasium's np_random"),
    ],
)
def test_async_workers_are_asked_only_what_they_can_send(
    tmp_path: Path, make: Any, why: str | None
) -> None:
    """A worker whose spec does not pickle (a lambda among the env's kwargs) or whose
    ``np_random`` raises ended when asked for it, and the loop with it: the spec is read off a
    sub-env built here, ``np_random`` asked only when the classes of that sub-env keep
    Gymnasium's own, else why the autoreset episodes' RNG state is unknown is noted."""
    from gymnasium.vector import AsyncVectorEnv

    path = tmp_path / "async.mcap"
    with RecordVectorEvidence(AsyncVectorEnv([make] * 2), path) as rec:
        rec.reset(seed=1)
        for _ in range(3 * LIMIT + 1):
            rec.step(np.zeros(2, np.int64))
    assert not check([path]).unreadable
    resets = open_evidence(path).resets().to_pylist()
    auto = [json.loads(r["notes"] or "[]") for r in resets if r["seed"] is None]
    assert len(resets) == 6  # (both sub-envs recorded to the end)
    expected = [] if why is None else [_NOT_ASKED.format(why=why)]
    assert len(auto) == 4 and all(n == expected for n in auto), auto


def test_async_workers_whose_env_puts_an_unpicklable_rng_are_not_asked_for_it(
    tmp_path: Path,
) -> None:
    """An env class keeping Gymnasium's ``np_random`` but putting an object that does not
    pickle in its private ``_np_random`` (at every reset) ended its worker when asked for it,
    and the loop with it: the sub-env built here is reset once and its ``np_random`` pickled,
    so the workers are not asked, and replay says why those episodes are not replayable."""
    from gymnasium.vector import AsyncVectorEnv

    path = tmp_path / "async.mcap"
    with RecordVectorEvidence(AsyncVectorEnv([locked_rng_made] * 2), path) as rec:
        rec.reset(seed=1)
        for _ in range(3 * LIMIT + 1):
            rec.step(np.zeros(2, np.int64))
    resets = open_evidence(path).resets().to_pylist()
    auto = [json.loads(r["notes"] or "[]") for r in resets if r["seed"] is None]
    # (before Python 3.11 it pickles, through LockedGenerator.__getattr__, and does not unpickle)
    said = "cannot pickle '_thread.lock' object" if sys.version_info >= (3, 11) else "'generator'"
    why = f"its np_random does not pickle ({said})"
    assert len(resets) == 6 and len(auto) == 4
    assert all(n == [_NOT_ASKED.format(why=why)] for n in auto), auto
    result = replay([path])
    assert result.count("identical") == 2 and result.count("not_replayable") == 4
    cause = "no seed or RNG state recorded for its reset: " + _NOT_ASKED.format(
        why=why
    ).removeprefix("rng_state_unavailable: ")
    assert {e.reason for e in result.episodes if e.status == "not_replayable"} == {cause}


def test_async_workers_of_a_gymnasium_env_are_asked_their_rng_and_replay(tmp_path: Path) -> None:
    """The common case: Gymnasium's own env made by ``gym.make``, no ResetRngInfo: the workers
    are asked for ``np_random`` after each ending, and every autoreset episode replays."""
    from gymnasium.vector import AsyncVectorEnv

    path = tmp_path / "async.mcap"
    fns = [lambda: gym.make("CartPole-v1", max_episode_steps=LIMIT)] * 2
    with RecordVectorEvidence(AsyncVectorEnv(fns), path) as rec:
        rec.reset()
        for _ in range(3 * LIMIT + 1):
            rec.step(np.zeros(2, np.int64))
    result = replay([path])
    assert len(result.episodes) == 6 and result.count("identical") == 6
