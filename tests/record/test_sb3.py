"""The Stable-Baselines3 recorder (record/sb3/) with real SB3: DummyVecEnv, SubprocVecEnv, stacks.

Each recording is checked against SB3's own accounting (``Monitor`` / ``VecMonitor`` returns
and lengths), replayed episode by episode, and checked. Training runs are short here; the
longer ones are in tests/test_long.py (``-m slow``).
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import threading
import warnings
from collections import defaultdict
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.classic_control import CartPoleEnv

pytest.importorskip("stable_baselines3")
torch = pytest.importorskip("torch")

from stable_baselines3 import PPO  # noqa: E402
from stable_baselines3.common.monitor import Monitor  # noqa: E402
from stable_baselines3.common.vec_env import (  # noqa: E402
    DummyVecEnv,
    SubprocVecEnv,
    VecFrameStack,
    VecMonitor,
    VecNormalize,
)

from episode_audit import (  # noqa: E402
    ConfigurationError,
    RecorderWarning,
    RecordEvidence,
    ResetRngInfo,
    check,
    open_evidence,
    replay,
)
from episode_audit.record.sb3 import RecordVecEnvEvidence  # noqa: E402
from tests.support.batching import InfoReading, messages  # noqa: E402
from tests.support.hostile import rewrite  # noqa: E402
from tests.support.limits import skipping_pendulum  # noqa: E402
from tests.support.unsaved import (  # noqa: E402
    UNSAVED_WARNING,
    assert_unseeded_episodes_are_not_replayable,
    short_pong,
)
from tests.support.worker_rng import (  # noqa: E402
    LIMIT,
    lambda_kwarg,
    locked_rng_made,
    raising_rng_made,
    rng_locked_rng,
    rng_raising_rng,
)

torch.set_num_threads(1)
N = 4
# SubprocVecEnv's default start methods import SB3 (and torch) again in every worker: seconds
# each on a busy machine. The tests fork instead (the recorder does not care how).
START = "fork"


def cartpole(**kwargs: Any) -> gym.Env[Any, Any]:
    return gym.make("CartPole-v1", **kwargs)


def monitored_cartpole() -> gym.Env[Any, Any]:
    return Monitor(gym.make("CartPole-v1"))


def rng_cartpole() -> gym.Env[Any, Any]:
    return ResetRngInfo(gym.make("CartPole-v1"))


def episodes(path: Path) -> list[dict[str, Any]]:
    return open_evidence(path).episodes().to_pylist()


def ended(path: Path) -> list[dict[str, Any]]:
    return [e for e in episodes(path) if e["outcome"] != "incomplete"]


def assert_replays_identical(path: Path) -> None:
    result = replay([path])
    bad = [(e.episode, e.status, e.reason, e.divergence) for e in result.episodes]
    bad = [b for b in bad if b[1] != "identical"]
    assert not bad, bad
    assert result.count("identical") + result.unstarted == len(episodes(path))


def assert_checks_clean(path: Path) -> None:
    result = check([path])
    errors = [f for f in result.findings if f.severity == "error"]
    assert not errors, errors


def assert_strict_clean(path: Path) -> None:
    """``episode-audit check --strict`` on ``path`` exits 0, with no ``--ignore``."""
    from typer.testing import CliRunner

    from episode_audit.cli import app

    result = CliRunner().invoke(app, ["check", str(path), "--strict"])
    assert result.exit_code == 0, result.output


def step_random(venv: Any, steps: int, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    venv.seed(seed)
    venv.reset()
    for _ in range(steps):
        venv.step(rng.integers(0, 2, size=venv.num_envs))


# ---------------------------------------------------------------- training with PPO


def test_ppo_on_dummy_vec_env_replays_identical(tmp_path: Path) -> None:
    path = tmp_path / "train.mcap"
    venv = DummyVecEnv([cartpole] * N)
    monitor = VecMonitor(RecordVecEnvEvidence(venv, path), str(tmp_path / "vm"))
    model = PPO("MlpPolicy", monitor, n_steps=128, n_epochs=1, batch_size=256, seed=3)
    model.learn(1024)
    monitor.close()
    eps = episodes(path)
    assert [e["seed"] for e in eps[:N]] == [3, 4, 5, 6]  # PPO(seed=3) seeds sub-env i with 3+i
    assert all(e["rng_state"] for e in eps[N:])  # autoreset episodes: the RNG state instead
    assert sum(e["length"] for e in eps) == 1024
    # VecMonitor's episodes are the file's ended ones (order: by ending step, per sub-env)
    csv = np.loadtxt(tmp_path / "vm.monitor.csv", delimiter=",", skiprows=2, ndmin=2)
    assert sorted((int(r[1]), float(r[0])) for r in csv) == sorted(
        (e["length"], round(e["return"], 6)) for e in ended(path)
    )
    assert_replays_identical(path)
    assert_checks_clean(path)


def test_dummy_vec_env_reset_infos_are_what_they_are_without_the_recorder(tmp_path: Path) -> None:
    """The ResetRngInfo the recorder installs puts the RNG state of each unseeded reset and
    autoreset in its info: the VecEnv's reset_infos, which a loop may read, lose that key once
    it is recorded; a ResetRngInfo of one's own (sub-env 0) keeps it."""
    thunks = [rng_cartpole, cartpole, cartpole]
    bare, base = DummyVecEnv(thunks), DummyVecEnv(thunks)
    venv = RecordVecEnvEvidence(base, tmp_path / "infos.mcap")
    for reset in (bare.reset, venv.reset):
        reset()
    assert [i.keys() for i in base.reset_infos] == [i.keys() for i in bare.reset_infos]
    assert "episode_audit.rng_state" in base.reset_infos[0]
    for actions in np.random.default_rng(1).integers(0, 2, size=(120, 3)):
        bare.step(actions)
        venv.step(actions)
        assert [i.keys() for i in base.reset_infos] == [i.keys() for i in bare.reset_infos]
    venv.close()
    bare.close()
    resets = open_evidence(tmp_path / "infos.mcap").resets().to_pylist()
    assert len(resets) > 9 and all(r["rng_state"] is not None for r in resets)
    assert_replays_identical(tmp_path / "infos.mcap")


def test_a_file_recorded_in_an_sb3_run_says_sb3_s_version(tmp_path: Path) -> None:
    """compare's version check flags an SB3 upgrade only if files say its version; recording
    never imports it (a process without SB3 records no version of it)."""
    import stable_baselines3

    path = tmp_path / "sb3.mcap"
    venv = RecordVecEnvEvidence(DummyVecEnv([cartpole] * 2), path)
    step_random(venv, 5)
    venv.close()
    assert open_evidence(path).run.versions["stable_baselines3"] == stable_baselines3.__version__
    fresh = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys; from episode_audit.record.settings import library_versions; "
            "v = library_versions(); "
            "print(sorted({'stable_baselines3', 'ale_py'} & (set(v) | set(sys.modules))))",
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    assert fresh.stdout.strip() == "[]", fresh


def test_returns_equal_monitor_for_every_episode_of_every_sub_env(tmp_path: Path) -> None:
    path = tmp_path / "train.mcap"
    venv = RecordVecEnvEvidence(DummyVecEnv([monitored_cartpole] * N), path)
    model = PPO("MlpPolicy", venv, n_steps=128, n_epochs=1, batch_size=256, seed=0)
    model.learn(1024)
    monitors = [venv.venv.envs[i].env for i in range(N)]  # ResetRngInfo(Monitor(...))
    assert all(isinstance(m, Monitor) for m in monitors)
    venv.close()
    by_env: dict[int, list[tuple[int, float]]] = defaultdict(list)
    for e in ended(path):
        by_env[e["env_index"]].append((e["length"], round(e["return"], 6)))
    for i, monitor in enumerate(monitors):
        assert by_env[i] == list(
            zip(monitor.get_episode_lengths(), monitor.get_episode_rewards(), strict=True)
        )
    assert_checks_clean(path)


def test_monitor_inside_the_sub_envs_replays(tmp_path: Path) -> None:
    path = tmp_path / "train.mcap"
    venv = RecordVecEnvEvidence(DummyVecEnv([monitored_cartpole] * 2), path)
    step_random(venv, 200)
    venv.close()
    assert_replays_identical(path)


def test_subproc_vec_env_with_reset_rng_info_replays_identical(tmp_path: Path) -> None:
    path = tmp_path / "subproc.mcap"
    venv = RecordVecEnvEvidence(SubprocVecEnv([rng_cartpole] * 2, start_method=START), path)
    step_random(venv, 300)
    venv.close()
    eps = episodes(path)
    assert len(eps) > 10
    assert [e["seed"] for e in eps[:2]] == [0, 1]
    assert_replays_identical(path)
    # the same actions on a DummyVecEnv give the same episodes
    local = tmp_path / "dummy.mcap"
    with RecordVecEnvEvidence(DummyVecEnv([cartpole] * 2), local) as dummy:
        step_random(dummy, 300)
    assert [(e["env_index"], e["length"], e["return"]) for e in episodes(local)] == [
        (e["env_index"], e["length"], e["return"]) for e in eps
    ]


def clipped_cartpole() -> gym.Env[Any, Any]:
    """A lambda in a wrapper's kwargs: the sub-env's spec holds it, and it does not pickle."""
    env = gym.make("CartPole-v1")
    return gym.wrappers.TransformObservation(
        env, lambda obs: np.clip(obs, -10, 10), env.observation_space
    )


def rng_clipped_cartpole() -> gym.Env[Any, Any]:
    return ResetRngInfo(clipped_cartpole())


class _Unprintable(gym.Wrapper[Any, Any, Any, Any]):
    """A sub-env whose text cannot be made (its ``__str__`` raises, as one formatting a field
    set at the first reset would): a worker asked for it would end."""

    def __str__(self) -> str:
        raise TypeError("unsupported format string passed to NoneType.__format__")


def unprintable_cartpole() -> gym.Env[Any, Any]:
    return _Unprintable(gym.make("CartPole-v1"))


@pytest.mark.parametrize("make", [clipped_cartpole, rng_clipped_cartpole, unprintable_cartpole])
def test_a_spec_that_does_not_pickle_leaves_subproc_workers_alive(
    tmp_path: Path, make: Any
) -> None:
    """A worker asked for such a spec fails to send it and ends: the recorder does not ask."""
    path = tmp_path / "subproc.mcap"
    with RecordVecEnvEvidence(SubprocVecEnv([make] * 2, start_method=START), path) as venv:
        step_random(venv, 30)
    spec = open_evidence(path).run.env_spec
    assert (spec is None) == (make is not unprintable_cartpole)
    assert {e["env_index"] for e in episodes(path)} == {0, 1}


def test_subproc_vec_env_without_reset_rng_info_says_what_to_do(tmp_path: Path) -> None:
    path = tmp_path / "subproc.mcap"
    with RecordVecEnvEvidence(SubprocVecEnv([cartpole] * 2, start_method=START), path) as venv:
        step_random(venv, 60)
    result = replay([path])
    assert result.count("identical") == 2  # the seeded first episodes
    auto = [e for e in result.episodes if e.status != "identical"]
    assert auto and all(e.status == "not_replayable" for e in auto)
    notes = [f.message for f in check([path]).findings if "rng_state" in f.code]
    assert notes
    ev = open_evidence(path)
    reset_notes = " ".join(str(n) for n in ev.resets().column("notes").to_pylist() if n)
    assert "wrapper_class=ResetRngInfo" in reset_notes


# ---------------------------------------------------------------- state snapshots


def normalized_cartpole() -> gym.Env[Any, Any]:
    return gym.wrappers.NormalizeObservation(gym.make("CartPole-v1", max_episode_steps=25))


def rng_normalized_cartpole() -> gym.Env[Any, Any]:
    return ResetRngInfo(normalized_cartpole())


def pong() -> gym.Env[Any, Any]:
    """ALE Pong: sticky actions and the reset draw from the emulator's RNG, not np_random."""
    ale_py = pytest.importorskip("ale_py")
    gym.register_envs(ale_py)
    return gym.make("ALE/Pong-v5", obs_type="ram", max_episode_steps=25)


def step_actions(venv: Any, steps: int, actions: int) -> None:
    rng = np.random.default_rng(0)
    venv.seed(3)
    venv.reset()
    for _ in range(steps):
        venv.step(rng.integers(0, actions, size=venv.num_envs))


def assert_snapshots_replay(path: Path) -> None:
    """Every episode has its snapshot, and replays identical, in order and alone."""
    eps = episodes(path)
    assert len(eps) >= 6 and all(e["rng_state"] for e in eps[2:])  # autoresets after the first
    assert_replays_identical(path)
    alone = replay([path], episodes=[eps[-3]["episode"]]).episodes
    assert [(e.status, e.reason) for e in alone] == [("identical", None)]
    ev = open_evidence(path)
    assert ev.run.layout["state_snapshots"] is True
    assert all(ev.resets().column("state").to_pylist())


@pytest.mark.parametrize(("make", "actions"), [(normalized_cartpole, 2), (pong, 6)])
def test_dummy_vec_env_sub_envs_are_snapshot_at_each_reset_and_autoreset(
    tmp_path: Path, make: Any, actions: int
) -> None:
    """NormalizeObservation's statistics carry across episodes; ALE's emulator RNG is not
    np_random: an autoreset episode replays only from the snapshot taken before its reset."""
    path = tmp_path / "dummy.mcap"
    with RecordVecEnvEvidence(DummyVecEnv([make] * 2), path) as venv:
        step_actions(venv, 80, actions)
    assert_snapshots_replay(path)


def test_subproc_workers_in_reset_rng_info_are_snapshot_in_the_worker(tmp_path: Path) -> None:
    path = tmp_path / "subproc.mcap"
    venv = SubprocVecEnv([rng_normalized_cartpole] * 2, start_method=START)
    with RecordVecEnvEvidence(venv, path) as venv:
        step_actions(venv, 80, 2)
    assert_snapshots_replay(path)


@pytest.mark.parametrize("vec", ["dummy, not installed", "subproc"])
def test_sub_envs_whose_state_is_not_snapshot_are_warned_of_and_checked(
    tmp_path: Path, vec: str
) -> None:
    """Without ResetRngInfo in each sub-env nothing snapshots it: the recorder warns as
    RecordVectorEvidence does, and check says the file's episodes cannot be replayed."""
    path = tmp_path / "unsnapshot.mcap"
    if vec == "subproc":
        base: Any = SubprocVecEnv([normalized_cartpole] * 2, start_method=START)
        kwargs = {}
    else:
        base, kwargs = DummyVecEnv([normalized_cartpole] * 2), {"install_rng_info": False}
    with pytest.warns(
        UserWarning,
        match=r"^episode-audit: RecordVecEnvEvidence: the recorded wrapper NormalizeObservation "
        r"keeps running statistics across episodes, which the file does not hold \(no state "
        r"snapshot\).* wrap each sub-env in episode_audit\.ResetRngInfo \(outermost, in the env "
        r"function\), which snapshots NormalizeObservation$",
    ):
        venv = RecordVecEnvEvidence(base, path, **kwargs)
    with venv:
        step_actions(venv, 30, 2)
    assert "state_snapshots" not in open_evidence(path).run.layout
    findings = [f.message for f in check([path]).findings if f.code == "not_replayable"]
    assert any("NormalizeObservation" in m for m in findings), findings
    assert replay([path]).count("not_replayable") == len(episodes(path))


def test_an_env_s_own_state_in_subproc_workers_without_reset_rng_info_is_warned_of(
    tmp_path: Path,
) -> None:
    """ALE's emulator state in workers that no ResetRngInfo snapshots: the episodes an
    unseeded reset began cannot be replayed, and the recorder and check say so."""
    path = tmp_path / "pong.mcap"
    with pytest.warns(UserWarning, match=UNSAVED_WARNING):
        venv = RecordVecEnvEvidence(SubprocVecEnv([short_pong] * 2, start_method=START), path)
    with venv:
        venv.seed(3)
        venv.reset()
        venv.step(np.array([0, 1]))
        venv.reset()  # (unseeded: SB3 forgets the seeds after a reset)
        venv.step(np.array([0, 1]))
    assert_unseeded_episodes_are_not_replayable(path)


def nested_pendulum() -> gym.Env[Any, Any]:
    """Pendulum's registered 200-step limit inside one of 500: the inner one ends episodes."""
    return ResetRngInfo(gym.wrappers.TimeLimit(gym.make("Pendulum-v1"), 500))


def skipped_pendulum() -> gym.Env[Any, Any]:
    """Pendulum's registered limit (200 of its steps) under a 4-step frame skip: 50 steps."""
    return ResetRngInfo(skipping_pendulum())


@pytest.mark.parametrize("vec", ["dummy", "subproc"])
@pytest.mark.parametrize(("make", "length"), [(nested_pendulum, 200), (skipped_pendulum, 50)])
def test_time_limits_the_recorder_cannot_read_are_not_called_divergences(
    tmp_path: Path, vec: str, make: Any, length: int
) -> None:
    """A SubprocVecEnv's workers answer for the outermost TimeLimit only, and a DummyVecEnv's
    reset inside its step zeroes the count of one under a frame skip before the recorder reads
    it: such truncations are recorded external, and replay does not call them divergences. An
    env whose limit truncates them at the recorded step (rebuilt under the frame skip from the
    spec, or by an env factory) repeats that ending: identical."""
    path = tmp_path / "limits.mcap"
    venv = (
        DummyVecEnv([make] * 2) if vec == "dummy" else SubprocVecEnv([make] * 2, start_method=START)
    )
    with RecordVecEnvEvidence(venv, path) as rec:
        rec.seed(0)
        rec.reset()
        for _ in range(length + 2):
            rec.step(np.zeros((2, 1), np.float32))
    ev = open_evidence(path)
    ended = [e for e in ev.episodes().to_pylist() if e["outcome"] != "incomplete"]
    readable = vec == "dummy" and make is nested_pendulum
    reason = "time_limit" if readable else "external"
    assert [(e["length"], e["truncation_reason"]) for e in ended] == [(length, reason)] * 2
    # (where a worker's limits sat around a frame skip, only an env factory says: below)
    unplaced = vec == "subproc" and make is skipped_pendulum
    result = replay([path], env_factory=make if unplaced else None)
    first = result.episodes[:2]
    cause = ev.run.layout.get("unread_time_limits")
    assert (cause or "").startswith(
        ""
        if readable
        else "the sub-envs ran in SubprocVecEnv workers"
        if vec == "subproc"
        else "a sub-env's TimeLimit under MaxAndSkipObservation counts the env's own steps"
    )
    if readable or make is skipped_pendulum:
        assert [(e.status, e.steps) for e in first] == [("identical", length)] * 2
        return
    assert [e.status for e in first] == ["not_replayable"] * 2  # (rebuilt with 500 only)
    assert first[0].reason is not None and first[0].reason.endswith(cause)


def limit_inside_skip() -> gym.Env[Any, Any]:
    """A limit of 5 Pendulum steps under a 2-step frame skip (ending each episode inside its
    3rd step), in one of 30 over it: the one a SubprocVecEnv worker answers for."""
    skip = gym.wrappers.MaxAndSkipObservation(gym.make("Pendulum-v1", max_episode_steps=5), 2)
    return ResetRngInfo(gym.wrappers.TimeLimit(skip, 30))


def test_subproc_workers_over_a_frame_skip_are_not_replayable_without_a_factory(
    tmp_path: Path,
) -> None:
    """The spec says 30 with the frame skip among its wrappers: rebuilt, the limit would sit
    under it and the one of 5 be gone (the last observations differ). Not a divergence."""
    path = tmp_path / "skip.mcap"
    venv = SubprocVecEnv([limit_inside_skip], start_method=START)
    with RecordVecEnvEvidence(venv, path) as rec:
        rec.seed(0)
        rec.reset()
        for _ in range(4):
            rec.step(np.zeros((1, 1), np.float32))
    ended = open_evidence(path).episodes().to_pylist()
    assert [(e["length"], e["truncation_reason"]) for e in ended[:1]] == [(3, "external")]
    result = replay([path])
    assert {e.status for e in result.episodes} == {"not_replayable"}
    assert {e.reason for e in result.episodes} == {
        "the sub-envs ran in SubprocVecEnv workers, whose wrapper chains the recorder cannot "
        "walk, and its spec holds MaxAndSkipObservation, which steps the env more than once a "
        "step: whether its TimeLimits sat over it or under it is unknown, so an env rebuilt from "
        "the spec may end an episode at another step; pass --env-factory MODULE:CALLABLE that "
        "builds the sub-env as recorded, or record with DummyVecEnv"
    }


class RemoteVecEnv(SubprocVecEnv):
    """A VecEnv of the user's own whose sub-envs are not in this process."""


@pytest.mark.parametrize("coded", [True, False], ids=["coded", "without-cause"])
def test_a_custom_vec_env_without_local_sub_envs_is_said_to_run_them_in_workers(
    tmp_path: Path, coded: bool
) -> None:
    """Its class is neither SubprocVecEnv nor DummyVecEnv: the cause code (or, in a file without
    it, the text) says its sub-envs ran in workers, not its class's name."""
    path = tmp_path / "remote.mcap"
    with RecordVecEnvEvidence(RemoteVecEnv([limit_inside_skip], start_method=START), path) as rec:
        rec.seed(0)
        rec.reset()
        for _ in range(4):
            rec.step(np.zeros((1, 1), np.float32))
    assert open_evidence(path).run.layout["unread_time_limits_cause"] == "workers"
    if not coded:

        def uncoded(meta: dict[str, str]) -> dict[str, str]:
            layout = json.loads(meta["layout"])
            del layout["unread_time_limits_cause"]
            return {**meta, "layout": json.dumps(layout)}

        path = rewrite(path, tmp_path / "old.mcap", run=uncoded)
    result = replay([path])
    assert {(e.status, e.reason) for e in result.episodes} == {
        (
            "not_replayable",
            "the sub-envs ran in RemoteVecEnv workers, whose wrapper chains the recorder cannot "
            "walk, and its spec holds MaxAndSkipObservation, which steps the env more than once "
            "a step: whether its TimeLimits sat over it or under it is unknown, so an env rebuilt "
            "from the spec may end an episode at another step; pass --env-factory "
            "MODULE:CALLABLE that builds the sub-env as recorded, or record with sub-envs in "
            "this process",
        )
    }


# ---------------------------------------------------------------- SAC on MuJoCo


def test_sac_on_mujoco_records_rewards_exactly(tmp_path: Path) -> None:
    pytest.importorskip("mujoco")
    from stable_baselines3 import SAC

    path = tmp_path / "sac.mcap"
    venv = RecordVecEnvEvidence(DummyVecEnv([lambda: gym.make("Reacher-v5")]), path)
    model = SAC("MlpPolicy", venv, learning_starts=100, batch_size=32, train_freq=10, seed=1)
    model.learn(300)
    _, rewards, _, _ = venv.step(np.zeros((1, 2), dtype=np.float32))
    assert rewards.dtype == np.float32  # what DummyVecEnv hands on, widened only for the file
    venv.close()
    assert sum(e["length"] for e in episodes(path)) == 301
    assert_replays_identical(path)
    assert_checks_clean(path)
    assert_strict_clean(path)


# ---------------------------------------------------------------- stacks


def test_under_vec_normalize_and_vec_frame_stack_replays_identical(tmp_path: Path) -> None:
    path = tmp_path / "norm.mcap"
    rec = RecordVecEnvEvidence(DummyVecEnv([cartpole] * 2), path)
    venv = VecFrameStack(VecNormalize(rec), 2)
    model = PPO("MlpPolicy", venv, n_steps=64, n_epochs=1, batch_size=128, seed=0)
    model.learn(256)
    venv.close()
    assert open_evidence(path).run.observation_space["shape"] == [4]
    assert_replays_identical(path)


def test_over_vec_normalize_is_recorded_and_says_it_cannot_replay(tmp_path: Path) -> None:
    path = tmp_path / "over.mcap"
    stack = VecNormalize(VecMonitor(DummyVecEnv([cartpole] * 2)))
    with pytest.warns(UserWarning, match="RecordVecEnvEvidence: VecNormalize under the recorder"):
        venv = RecordVecEnvEvidence(stack, path)  # (as RecordVectorEvidence warns)
    step_random(venv, 100)
    venv.close()
    run = open_evidence(path).run
    assert run.layout["sub_envs"] is False
    assert "VecNormalize under the recorder" in run.layout["replay_note"]
    assert any("VecNormalize, VecMonitor" in n for n in run.recorder["notes"])
    result = replay([path])
    assert result.count("not_replayable") == len(episodes(path))
    assert any(f.code == "not_replayable" for f in check([path]).findings)


@pytest.mark.parametrize("norm_obs", [True, False])
def test_over_vec_normalize_the_normalised_observations_are_not_blamed_on_the_env(
    tmp_path: Path, norm_obs: bool
) -> None:
    """VecNormalize keeps CartPole's bounded space: the space recorded is its ±clip_obs."""
    path = tmp_path / "over.mcap"
    stack = VecNormalize(DummyVecEnv([cartpole] * 2), norm_obs=norm_obs, clip_obs=5.0)
    with pytest.warns(UserWarning, match="VecNormalize under the recorder"):
        venv = RecordVecEnvEvidence(stack, path)
    step_random(venv, 300)
    assert venv.observation_space == stack.observation_space  # (the loop's is VecNormalize's)
    venv.close()
    run = open_evidence(path).run
    codes = {f.code for f in check([path]).findings}
    assert "observation_out_of_space" not in codes
    if norm_obs:
        assert run.observation_space["low"] == -5.0 and run.observation_space["high"] == 5.0
        assert "the space recorded is its range, [-5, 5], float32" in " ".join(
            run.recorder["notes"]
        )
    else:  # (the env's own space: nothing normalised it)
        assert run.observation_space["dtype"] == "float32" and "[-5, 5]" not in str(run.recorder)


def test_over_vec_normalize_of_reacher_names_it_and_leaves_the_terms_unchecked(
    tmp_path: Path,
) -> None:
    pytest.importorskip("mujoco")
    path = tmp_path / "over.mcap"
    base = DummyVecEnv([lambda: gym.make("Reacher-v5", max_episode_steps=20)] * 2)
    with pytest.warns(UserWarning, match="VecNormalize under the recorder"):
        venv = RecordVecEnvEvidence(VecNormalize(base, norm_obs=False), path)
    venv.seed(0)
    venv.reset()
    for _ in range(60):
        venv.step(np.zeros((2, 2), dtype=np.float32) + 0.5)
    venv.close()
    layout = open_evidence(path).run.layout
    assert layout["reward_wrappers"] == [
        "stable_baselines3.common.vec_env.vec_normalize:VecNormalize"
    ]
    findings = check([path]).findings
    assert "terms_sum_mismatch" not in {f.code for f in findings}, findings
    (found,) = [f.message for f in findings if f.code == "rewards_changed"]
    assert found.startswith(
        "the recorded rewards and returns are VecNormalize's, not the env's: the recorder sat "
        "over it; the reward terms of "
    ) and found.endswith(
        "were not checked against these rewards, the terms being the env's "
        "(the wrappers change the reward, not its terms): record beneath it (innermost) for the "
        "env's own rewards, checked against their terms"
    ), found


def normalized_reacher() -> gym.Env[Any, Any]:
    return gym.wrappers.NormalizeReward(gym.make("Reacher-v5", max_episode_steps=5))


def hidden_normalized_reacher() -> gym.Env[Any, Any]:
    """Its spec is not asked of the workers (a function-taking wrapper): none is recorded."""
    return gym.wrappers.TransformObservation(normalized_reacher(), lambda o: o, None)


@pytest.mark.parametrize("make", [normalized_reacher, hidden_normalized_reacher])
def test_reward_wrappers_inside_subproc_sub_envs_leave_the_terms_unchecked(
    tmp_path: Path, make: Any
) -> None:
    """NormalizeReward in each worker's sub-env: the rewards are its, not the terms' sum."""
    pytest.importorskip("mujoco")
    path = tmp_path / "inside.mcap"
    with warnings.catch_warnings():  # (NormalizeReward's statistics are not snapshot: said)
        warnings.simplefilter("ignore", UserWarning)
        venv = RecordVecEnvEvidence(SubprocVecEnv([make] * 2, start_method=START), path)
    with venv:
        venv.seed(0)
        venv.reset()
        for _ in range(12):
            venv.step(np.full((2, 2), 0.5, dtype=np.float32))
    run = open_evidence(path).run
    assert (run.env_spec is None) == (make is hidden_normalized_reacher)
    assert run.layout["reward_wrappers"] == ["gymnasium.wrappers.stateful_reward:NormalizeReward"]
    findings = check([path]).findings
    assert "terms_sum_mismatch" not in {f.code for f in findings}, findings
    (found,) = [f.message for f in findings if f.code == "rewards_changed"]
    assert found.startswith("the recorded rewards and returns are NormalizeReward's"), found


def normalized_rewards() -> gym.Env[Any, Any]:
    return gym.wrappers.NormalizeReward(gym.make("CartPole-v1"))


def hidden_normalized_rewards() -> gym.Env[Any, Any]:
    """No spec of it is recorded (a function-taking wrapper): found by env_is_wrapped only."""
    return gym.wrappers.TransformObservation(normalized_rewards(), lambda o: o, None)


def specless_normalized_rewards() -> gym.Env[Any, Any]:
    """No spec at all (not made by gym.make)."""
    from gymnasium.envs.classic_control import CartPoleEnv

    return gym.wrappers.NormalizeReward(gym.wrappers.TimeLimit(CartPoleEnv(), 50))


def clipped_normalized_rewards() -> gym.Env[Any, Any]:
    """No spec (not made by gym.make): NormalizeReward inside ClipReward, ResetRngInfo over them."""
    from gymnasium.envs.classic_control import CartPoleEnv

    env = gym.wrappers.NormalizeReward(gym.wrappers.TimeLimit(CartPoleEnv(), 50))
    return ResetRngInfo(gym.wrappers.ClipReward(env, -1.0, 1.0))


@pytest.mark.parametrize("vec_env", ["dummy", "subproc"])
def test_reward_wrappers_of_sub_envs_are_listed_in_their_order(
    tmp_path: Path, vec_env: str
) -> None:
    """Innermost first, whether walked here or, without a spec, by ResetRngInfo in a worker
    (clip then normalise is not normalise then clip)."""
    path = tmp_path / "clipped.mcap"
    base = (
        DummyVecEnv([clipped_normalized_rewards] * 2)
        if vec_env == "dummy"
        else SubprocVecEnv([clipped_normalized_rewards] * 2, start_method=START)
    )
    with warnings.catch_warnings():  # (NormalizeReward's statistics are not snapshot: said)
        warnings.simplefilter("ignore", UserWarning)
        RecordVecEnvEvidence(base, path).close()
    assert open_evidence(path).run.layout["reward_wrappers"] == [
        "gymnasium.wrappers.stateful_reward:NormalizeReward",
        "gymnasium.wrappers.transform_reward:ClipReward",
    ]


@pytest.mark.parametrize(
    "make", [normalized_rewards, hidden_normalized_rewards, specless_normalized_rewards]
)
def test_normalize_reward_in_subproc_workers_is_warned_of_with_or_without_a_spec(
    tmp_path: Path, make: Any
) -> None:
    """Its statistics, which no state adapter snapshots in a worker, are warned of at
    construction whether the sub-envs' spec names it or only the workers' chains hold it."""
    path = tmp_path / "normalized.mcap"
    base = SubprocVecEnv([make] * 2, start_method=START)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        venv = RecordVecEnvEvidence(base, path)
    venv.close()
    said = [str(w.message) for w in caught if issubclass(w.category, RecorderWarning)]
    assert any(
        re.match(
            r"^episode-audit: RecordVecEnvEvidence: the recorded wrapper NormalizeReward keeps "
            r"running statistics across episodes, which the file does not hold \(no state "
            r"snapshot\)",
            message,
        )
        for message in said
    ), said
    run = open_evidence(path).run
    assert (run.env_spec is None) == (make is not normalized_rewards)


def test_a_trusted_monitor_over_an_unregistered_id_is_put_on_as_recorded(tmp_path: Path) -> None:
    """Gymnasium's make refuses a spec naming Monitor (kwargs null, no RecordConstructorArgs);
    trusted, the env is made from its entry point and Monitor put on, as for a registered id."""
    path = tmp_path / "monitor.mcap"
    gym.register("Unregistered-v0", entry_point="gymnasium.envs.classic_control:CartPoleEnv")
    try:
        with RecordEvidence(Monitor(gym.make("Unregistered-v0")), path) as env:
            for seed in (0, 1):
                env.reset(seed=seed)
                for _ in range(5):
                    env.step(1)
    finally:
        del gym.registry["Unregistered-v0"]
    result = replay([path], trust_entry_points=True)
    assert {(e.status, e.reason) for e in result.episodes} == {("identical", None)}


def test_over_transparent_wrappers_replays_identical(tmp_path: Path) -> None:
    path = tmp_path / "over.mcap"
    venv = RecordVecEnvEvidence(
        VecNormalize(VecMonitor(DummyVecEnv([cartpole] * 2)), norm_obs=False, norm_reward=False),
        path,
    )
    step_random(venv, 100)
    venv.close()
    assert open_evidence(path).run.layout["sub_envs"] is True
    assert_replays_identical(path)


# ---------------------------------------------------------------- SB3's step, read right


def _steps_to_fall(seed: int) -> int:
    env = gym.make("CartPole-v1")
    env.reset(seed=seed)
    for t in range(1, 500):
        if env.step(0)[2]:
            return t
    raise AssertionError("CartPole did not fall")


def test_terminated_at_the_step_limit_keeps_both_flags(tmp_path: Path) -> None:
    limit = _steps_to_fall(7)
    path = tmp_path / "both.mcap"
    with RecordVecEnvEvidence(
        DummyVecEnv([lambda: cartpole(max_episode_steps=limit)]), path
    ) as venv:
        venv.seed(7)
        venv.reset()
        for _ in range(limit):
            venv.step(np.array([0]))
    first = episodes(path)[0]
    assert (first["length"], first["terminated"], first["truncated"]) == (limit, True, True)
    assert first["outcome"] == "failure"  # the task's ending counts
    assert_replays_identical(path)


def test_seeds_and_options_set_before_reset_are_recorded(tmp_path: Path) -> None:
    path = tmp_path / "options.mcap"
    with RecordVecEnvEvidence(DummyVecEnv([cartpole] * 2), path) as venv:
        venv.seed(40)
        venv.set_options([{"low": -0.01, "high": 0.01}, {}])
        venv.reset()
        venv.step(np.array([0, 1]))
        venv.reset()  # unseeded: RNG states
        venv.step(np.array([0, 1]))
    eps = episodes(path)
    assert [(e["seed"], e["options"]) for e in eps[:2]] == [
        (40, '{"low":-0.01,"high":0.01}'),
        (41, None),
    ]
    assert [e["seed"] for e in eps[2:]] == [None, None]
    assert all(e["rng_state"] for e in eps[2:])
    assert_replays_identical(path)


def test_a_sub_env_that_raises_ends_the_episodes_as_error(tmp_path: Path) -> None:
    def broken() -> gym.Env[Any, Any]:
        env = cartpole()
        env.unwrapped.step = lambda action: (_ for _ in ()).throw(RuntimeError("boom"))  # type: ignore[method-assign]
        return env

    path = tmp_path / "error.mcap"
    venv = RecordVecEnvEvidence(DummyVecEnv([cartpole, broken]), path)
    venv.reset()
    with pytest.raises(RuntimeError, match="boom"):
        venv.step(np.array([0, 0]))
    venv.close()
    assert [e["outcome"] for e in episodes(path)] == ["error", "error"]


# ---------------------------------------------------------------- misuse, packaging


def test_record_vector_evidence_refuses_an_sb3_vec_env(tmp_path: Path) -> None:
    from episode_audit import RecordVectorEvidence

    with pytest.raises(ConfigurationError, match=r"DummyVecEnv, a Stable-Baselines3 VecEnv: .*"):
        RecordVectorEvidence(DummyVecEnv([cartpole]), tmp_path / "x.mcap")  # type: ignore[arg-type]
    assert not (tmp_path / "x.mcap").exists()


def test_record_vec_env_evidence_refuses_a_gymnasium_env(tmp_path: Path) -> None:
    with pytest.raises(ConfigurationError, match="records a Stable-Baselines3 VecEnv, actually"):
        RecordVecEnvEvidence(cartpole(), tmp_path / "x.mcap")  # type: ignore[arg-type]
    assert not (tmp_path / "x.mcap").exists()


def test_importing_episode_audit_imports_neither_sb3_nor_torch() -> None:
    code = (
        "import sys, episode_audit; "
        "print(sorted(m for m in ('stable_baselines3', 'torch') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
    from episode_audit import RecordVecEnvEvidence as lazy

    assert lazy is RecordVecEnvEvidence


def test_between_step_async_and_step_wait_only_another_thread_counts_as_inside(
    tmp_path: Path,
) -> None:
    from episode_audit.record.file import _inside

    path = tmp_path / "a.mcap"
    venv = RecordVecEnvEvidence(DummyVecEnv([cartpole] * 2), path)
    venv.reset()
    venv.step(np.zeros(2, dtype=np.int64))
    venv.step_async(np.ones(2, dtype=np.int64))
    # close() from this thread (an exception between the two calls) need not wait for itself
    assert venv._busy and not _inside(venv)
    seen: list[bool] = []
    other = threading.Thread(target=lambda: seen.append(_inside(venv)))
    other.start()
    other.join()
    assert seen == [True]  # another thread's close() waits for the step to end
    venv.close()
    assert open_evidence(path).finished and open_evidence(path).steps().num_rows == 2


# ---------------------------------------------------------------- make_vec_env + RecordEvidence


class PathPerSubEnv:
    """A ``wrapper_class`` giving each sub-env of a ``DummyVecEnv`` a path of its own (in order)."""

    def __init__(self, template: str) -> None:
        self.template = template
        self.made = 0

    def __call__(self, env: gym.Env[Any, Any]) -> gym.Env[Any, Any]:
        from episode_audit import RecordEvidence

        path = self.template.format(self.made)
        self.made += 1
        return RecordEvidence(env, path)


def test_make_vec_env_with_record_evidence_per_sub_env(tmp_path: Path) -> None:
    from stable_baselines3.common.env_util import make_vec_env

    venv = make_vec_env(
        "CartPole-v1", N, seed=0, wrapper_class=PathPerSubEnv(str(tmp_path / "train-{}.mcap"))
    )
    model = PPO("MlpPolicy", venv, n_steps=64, n_epochs=1, batch_size=256, seed=0)
    model.learn(256)
    monitors = [e.env for e in venv.envs]  # RecordEvidence(Monitor(...))
    venv.close()
    for i, monitor in enumerate(monitors):
        path = tmp_path / f"train-{i}.mcap"
        assert [(e["length"], round(e["return"], 6)) for e in ended(path)] == list(
            zip(monitor.get_episode_lengths(), monitor.get_episode_rewards(), strict=True)
        )
        assert episodes(path)[0]["seed"] == i
        assert_checks_clean(path)


def test_make_vec_env_with_an_index_template(tmp_path: Path) -> None:
    from stable_baselines3.common.env_util import make_vec_env

    from episode_audit import RecordEvidence

    template = str(tmp_path / "train-{index}.mcap")
    venv = make_vec_env(
        "CartPole-v1", N, wrapper_class=RecordEvidence, wrapper_kwargs={"path": template}
    )
    step_random(venv, 50)
    venv.close()
    assert sorted(p.name for p in tmp_path.glob("*.mcap")) == [f"train-{i}.mcap" for i in range(N)]


# ---------------------------------------------------------------- check --strict


def _train_recorder(tmp_path: Path) -> tuple[list[Path], list[Monitor]]:
    path = tmp_path / "train.mcap"
    venv = RecordVecEnvEvidence(DummyVecEnv([monitored_cartpole] * N), path)
    PPO("MlpPolicy", venv, n_steps=128, n_epochs=1, batch_size=256, seed=0).learn(2048)
    monitors = [venv.venv.envs[i].env for i in range(N)]  # ResetRngInfo(Monitor(...))
    venv.close()
    return [path] * N, monitors


def _train_make_vec_env(tmp_path: Path) -> tuple[list[Path], list[Monitor]]:
    from stable_baselines3.common.env_util import make_vec_env

    from episode_audit import RecordEvidence

    template = str(tmp_path / "train-{index}.mcap")
    venv = make_vec_env(
        "CartPole-v1", N, seed=0, wrapper_class=RecordEvidence, wrapper_kwargs={"path": template}
    )
    PPO("MlpPolicy", venv, n_steps=128, n_epochs=1, batch_size=256, seed=0).learn(2048)
    monitors = [e.env for e in venv.envs]  # RecordEvidence(Monitor(...))
    venv.close()
    return [tmp_path / f"train-{i}.mcap" for i in range(N)], monitors


@pytest.mark.parametrize("train", [_train_recorder, _train_make_vec_env])
def test_check_strict_passes_ppo_training_on_cartpole(tmp_path: Path, train: Any) -> None:
    """Strict check clean with no --ignore; returns equal Monitor's; every episode identical."""
    paths, monitors = train(tmp_path)
    one_file = len(set(paths)) == 1  # sub-env i is stream i of it; else file i
    for i, (path, monitor) in enumerate(zip(paths, monitors, strict=True)):
        index = i if one_file else 0
        mine = [
            (e["length"], round(e["return"], 6)) for e in ended(path) if e["env_index"] == index
        ]
        assert monitor.get_episode_lengths()  # episodes ended
        assert mine == list(
            zip(monitor.get_episode_lengths(), monitor.get_episode_rewards(), strict=True)
        )
    for path in sorted(set(paths)):
        assert_strict_clean(path)
        assert_replays_identical(path)


def test_check_strict_passes_ppo_training_on_reacher(tmp_path: Path) -> None:
    pytest.importorskip("mujoco")
    path = tmp_path / "reacher.mcap"
    make = [lambda: Monitor(gym.make("Reacher-v5"))] * 2
    venv = RecordVecEnvEvidence(DummyVecEnv(make), path)
    PPO("MlpPolicy", venv, n_steps=128, n_epochs=1, batch_size=256, seed=0).learn(512)
    venv.close()
    assert ended(path)
    assert_strict_clean(path)
    assert_replays_identical(path)


# ---------------------------------------------------------------- evaluation


def test_record_evaluation_tags_the_checkpoint_and_step(tmp_path: Path) -> None:
    from episode_audit.record.sb3 import record_evaluation

    model = PPO("MlpPolicy", DummyVecEnv([cartpole]), n_steps=64, n_epochs=1, seed=0)
    model.learn(64)
    eval_env = VecNormalize(VecMonitor(DummyVecEnv([cartpole] * 2)), norm_reward=False)
    eval_env.seed(100)
    path = tmp_path / "eval.mcap"
    rewards, lengths = record_evaluation(
        model, eval_env, path, n_eval_episodes=4, checkpoint="ckpt/ppo_{step}.zip"
    )
    assert len(rewards) == len(lengths) == 4
    run = open_evidence(path).run
    assert run.tags["training_step"] == str(model.num_timesteps)
    assert run.tags["checkpoint"] == f"ckpt/ppo_{model.num_timesteps}.zip"
    assert run.tags["evaluation"] == "evaluate_policy"
    assert eval_env.venv.venv is not None and not isinstance(
        eval_env.venv.venv, RecordVecEnvEvidence
    )  # the recorder came out again
    counted = sorted((n, round(r, 4)) for n, r in zip(lengths, rewards, strict=True))
    recorded = sorted((e["length"], round(e["return"], 4)) for e in ended(path))
    assert set(counted) <= set(recorded)
    assert_replays_identical(path)  # recorded under VecNormalize: raw steps
    assert_checks_clean(path)


def test_record_eval_callback_writes_one_file_per_evaluation(tmp_path: Path) -> None:
    from episode_audit import RecordEvalCallback

    eval_env = VecMonitor(DummyVecEnv([cartpole]))
    callback = RecordEvalCallback(
        eval_env, str(tmp_path / "evals" / "eval-{step}.mcap"), eval_freq=64, n_eval_episodes=2
    )
    train_env = VecMonitor(DummyVecEnv([cartpole]))
    model = PPO("MlpPolicy", train_env, n_steps=64, n_epochs=1, seed=0)
    model.learn(128, callback=callback)
    assert [p.name for p in callback.recorded] == ["eval-64.mcap", "eval-128.mcap"]
    for path, step in zip(callback.recorded, (64, 128), strict=True):
        tags = open_evidence(path).run.tags
        assert (tags["evaluation"], tags["training_step"]) == ("EvalCallback", str(step))
        assert len(ended(path)) >= 2
        assert_replays_identical(path)
    assert callback.eval_env is eval_env


def test_steps_with_reward_terms_are_batched_as_sub_envs_would_record_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A DummyVecEnv of MuJoCo envs (reward terms in every info, SB3's own keys beside them)
    takes the batched path, the endings included, and the file holds what recording it
    sub-env by sub-env holds."""
    reading = InfoReading(monkeypatch, "list_terms")
    actions = np.random.default_rng(3).uniform(-1, 1, size=(170, 3, 2)).astype(np.float32)
    files, batched = {}, {}
    for kind in ("batched", "sub_envs"):
        reading.run(declining=kind == "sub_envs")
        files[kind] = tmp_path / f"{kind}.mcap"
        venv = RecordVecEnvEvidence(DummyVecEnv([lambda: gym.make("Reacher-v5")] * 3), files[kind])
        venv.seed(4)
        venv.reset()
        for action in actions:
            venv.step(action)
        venv.close()
        batched[kind] = sum(reading.taken)
    assert batched["batched"] > 150 and batched["sub_envs"] == 0 and len(reading.taken) > 150
    assert messages(files["batched"]) == messages(files["sub_envs"])
    with open_evidence(tmp_path / "batched.mcap") as evidence:
        episodes = evidence.episodes()
    totals = episodes.column("term_totals").to_pylist()
    assert len(totals) >= 9 and all(
        dict(t).keys() == {"reward_dist", "reward_ctrl"} for t in totals
    )
    assert set(episodes.column("outcome").to_pylist()) >= {"truncated"}


def test_record_eval_callback_refuses_an_earlier_runs_files_before_training(
    tmp_path: Path,
) -> None:
    """Met at the first evaluation, an earlier run's eval-64.mcap stopped learn() mid-run;
    a learn() that continues this run (its files' steps are behind it) goes on."""
    from episode_audit import RecordEvalCallback

    template = str(tmp_path / "evals" / "eval-{step}.mcap")

    def learn(steps: int, model: Any = None, **kwargs: Any) -> Any:
        callback = RecordEvalCallback(
            VecMonitor(DummyVecEnv([cartpole])), template, eval_freq=64, n_eval_episodes=1
        )
        if model is None:
            model = PPO("MlpPolicy", VecMonitor(DummyVecEnv([cartpole])), n_steps=64, seed=0)
        model.learn(steps, callback=callback, **kwargs)
        return model

    model = learn(64)
    with pytest.raises(ConfigurationError, match=r"eval-64\.mcap: an evaluation file an earlier"):
        learn(64)  # (a new run: its first evaluation would be eval-64.mcap)
    learn(64, model, reset_num_timesteps=False)  # (this run goes on: eval-128.mcap)
    assert sorted(p.name for p in (tmp_path / "evals").iterdir()) == [
        "eval-128.mcap",
        "eval-64.mcap",
    ]


@pytest.mark.parametrize("make", [rng_locked_rng, rng_raising_rng])
def test_reset_rng_info_in_subproc_workers_answers_for_an_rng_they_cannot_send(
    tmp_path: Path, make: Any
) -> None:
    """An unseeded reset() reads each sub-env's RNG state first: asked of its ResetRngInfo, not
    for its ``np_random``, which would end a worker when it raises or does not pickle."""
    path = tmp_path / "subproc.mcap"
    with RecordVecEnvEvidence(SubprocVecEnv([make] * 2, start_method=START), path) as venv:
        venv.seed(1)
        venv.reset()
        venv.reset()  # unseeded, before any autoreset's info had a state: read from the workers
        for _ in range(2 * LIMIT):
            venv.step(np.zeros(2, np.int64))
    unseeded = [e for e in open_evidence(path).episodes().to_pylist() if e["seed"] is None]
    assert len(unseeded) >= 4 and all(e["rng_state"] for e in unseeded)


_NOT_SENT = (
    "rng_state_unavailable: its worker was not asked for its np_random, which could end it: "
    "{why}; wrap each sub-env in episode_audit.ResetRngInfo"
)
_UNSENDABLE = "reading it raises or it does not pickle"


@pytest.mark.parametrize(
    ("make", "whys"),
    [
        (lambda_kwarg, [None, None]),  # (its spec does not pickle: not asked for)
        (raising_rng_made, [_UNSENDABLE, _UNSENDABLE]),
        (locked_rng_made, [None, _UNSENDABLE]),  # (a locked generator from its first reset)
        (CartPoleEnv, ["no wrapper in it answers whether it can be sent"] * 2),
    ],
)
def test_subproc_workers_are_asked_only_what_they_can_send(
    tmp_path: Path, make: Any, whys: list[str | None]
) -> None:
    """A worker asked for a spec or an ``np_random`` it cannot send (reading it raises, or it
    does not pickle) ended, and the loop with it: the workers are asked first, in a bool,
    whether they can send it (SB3's ``env_is_wrapped``); those that cannot are not asked, and
    the unseeded resets' episodes say why their RNG state is unknown."""
    path = tmp_path / "subproc.mcap"
    with RecordVecEnvEvidence(SubprocVecEnv([make] * 2, start_method=START), path) as venv:
        for _ in range(2):  # unseeded resets, each reading the RNG states first
            venv.reset()
            for _ in range(LIMIT + 1):
                venv.step(np.zeros(2, np.int64))
    assert not check([path]).unreadable
    spec = open_evidence(path).run.env_spec
    assert (spec is None) == (make in (lambda_kwarg, CartPoleEnv))
    resets = open_evidence(path).resets().to_pylist()
    first = [r for r in resets if "inside its worker" not in (r["notes"] or "")]  # reset()'s
    first.sort(key=lambda r: r["episode"])
    assert len(first) == 4
    for r, why in zip(first, [whys[0]] * 2 + [whys[1]] * 2, strict=True):
        notes = json.loads(r["notes"]) if r["notes"] else []
        asked = why is None
        assert (r["rng_state"] is not None) == asked
        assert asked or _NOT_SENT.format(why=why) in notes, notes
