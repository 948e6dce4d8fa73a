from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import textwrap
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pyarrow as pa
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from episode_audit import RecordEvidence, RecordVectorEvidence, open_evidence
from episode_audit._usercode import load_callable
from episode_audit.cli import app
from episode_audit.errors import ConfigurationError, ReplayError
from episode_audit.format.columns import TERMS_TYPE
from episode_audit.format.options import decode_typed
from episode_audit.record.time_limits import plain_time_limit
from episode_audit.replay import build_env, replay
from episode_audit.replay.compare import _terms_rows_equal
from episode_audit.replay.compare import terms_equal as _terms_equal
from episode_audit.replay.recorded import row_ranges as _row_ranges
from episode_audit.replay.returned import _rewards
from tests.support.envs import ScriptedEnv
from tests.support.hostile import rewrite

REPO = Path(__file__).resolve().parents[2]


def record_random(
    path: Path, env_id: str, episodes: int, *, max_episode_steps: int | None = None
) -> Path:
    """Record `episodes` random episodes; every third reset is unseeded."""
    kwargs: dict[str, Any] = {}
    if max_episode_steps is not None:
        kwargs["max_episode_steps"] = max_episode_steps
    with RecordEvidence(gym.make(env_id, **kwargs), path) as env:
        env.action_space.seed(123)
        for e in range(episodes):
            env.reset(seed=None if e % 3 == 2 else 1000 + e)
            done = False
            while not done:
                _, _, term, trunc, _ = env.step(env.action_space.sample())
                done = term or trunc
    return path


def test_cartpole_replays_identically_including_unseeded_resets(tmp_path: Path) -> None:
    path = record_random(tmp_path / "cp.mcap", "CartPole-v1", 24, max_episode_steps=15)
    result = replay([path])
    assert [e.status for e in result.episodes] == ["identical"] * 24, result.episodes
    assert result.ok
    assert sum(e.steps for e in result.episodes) > 24


@pytest.mark.parametrize(("env_id", "limit"), [("Reacher-v5", None), ("HalfCheetah-v5", 60)])
def test_mujoco_replays_identically(tmp_path: Path, env_id: str, limit: int | None) -> None:
    pytest.importorskip("mujoco")
    path = record_random(tmp_path / "mj.mcap", env_id, 21, max_episode_steps=limit)
    result = replay([path])
    assert result.count("identical") == 21, [e for e in result.episodes if e.status != "identical"]


def make_heavier_cartpole(**kwargs: Any) -> gym.Env[Any, Any]:
    env = gym.make("CartPole-v1", **kwargs)
    env.unwrapped.masspole = 0.3  # type: ignore[attr-defined]
    env.unwrapped.total_mass = env.unwrapped.masspole + env.unwrapped.masscart  # type: ignore[attr-defined]
    env.unwrapped.polemass_length = env.unwrapped.masspole * env.unwrapped.length  # type: ignore[attr-defined]
    return env


def test_changed_env_diverges_and_names_step_and_field(tmp_path: Path) -> None:
    path = record_random(tmp_path / "cp.mcap", "CartPole-v1", 2)
    result = replay([path], env_factory=make_heavier_cartpole)
    assert not result.ok
    first = result.episodes[0]
    assert first.status == "diverged"
    assert first.divergence is not None
    assert first.divergence.field == "observation"
    assert first.divergence.step == 0
    assert first.divergence.max_abs_diff is not None and first.divergence.max_abs_diff > 0
    assert "step 0: observation expected" in first.divergence.describe()


def test_atol_tolerates_small_differences(tmp_path: Path) -> None:
    path = record_random(tmp_path / "cp.mcap", "CartPole-v1", 1, max_episode_steps=3)
    result = replay(
        [path], env_factory=lambda: make_heavier_cartpole(max_episode_steps=3), atol=1.0
    )
    assert result.ok


def test_episode_selection(tmp_path: Path) -> None:
    path = record_random(tmp_path / "cp.mcap", "CartPole-v1", 5)
    result = replay([path], episodes=[1, 3])
    assert [e.episode for e in result.episodes] == [1, 3]


EVIL_RECORDER = """
import pathlib, sys, gymnasium as gym
here = pathlib.Path(sys.argv[1])
(here / "evil_module_for_test.py").write_text(
    "import pathlib\\n"
    f"pathlib.Path({str(here / 'IMPORTED')!r}).write_text('yes')\\n"
    "from gymnasium.envs.classic_control import CartPoleEnv as Env\\n"
)
sys.path.insert(0, str(here))
gym.register("EvilTest-v0", entry_point="evil_module_for_test:Env", max_episode_steps=5)
from episode_audit import RecordEvidence
with RecordEvidence(gym.make("EvilTest-v0"), here / "evil.mcap") as env:
    env.reset(seed=1)
    for _ in range(5):
        env.step(0)
(here / "IMPORTED").unlink()
"""


def test_replay_never_imports_a_module_named_in_the_file(tmp_path: Path) -> None:
    subprocess.run([sys.executable, "-c", EVIL_RECORDER, str(tmp_path)], check=True, cwd=REPO)
    assert not (tmp_path / "IMPORTED").exists()
    sys.path.insert(0, str(tmp_path))
    try:
        result = replay([tmp_path / "evil.mcap"])
        assert "evil_module_for_test" not in sys.modules
        assert not (tmp_path / "IMPORTED").exists()
        (episode,) = result.episodes
        assert episode.status == "not_replayable"
        assert episode.reason is not None and "--trust-entry-points" in episode.reason
        trusted = replay([tmp_path / "evil.mcap"], trust_entry_points=True)
        assert (tmp_path / "IMPORTED").exists()
        assert trusted.episodes[0].status == "identical"
    finally:
        sys.path.remove(str(tmp_path))
        sys.modules.pop("evil_module_for_test", None)


def _stack(env: gym.Env[Any, Any]) -> list[str]:
    names = []
    while isinstance(env, gym.Wrapper):
        names.append(type(env).__name__)
        env = env.env
    return [*names, type(env).__name__]


def test_the_replay_env_leaves_out_gymnasiums_development_checks(tmp_path: Path) -> None:
    """No PassiveEnvChecker or OrderEnforcing (they never change a step's result); the time
    limit and recorded Gymnasium wrappers stay, in their order."""
    plain = record_random(tmp_path / "plain.mcap", "CartPole-v1", 2, max_episode_steps=7)
    assert _stack(gym.make("CartPole-v1")) == [
        "TimeLimit",
        "OrderEnforcing",
        "PassiveEnvChecker",
        "CartPoleEnv",
    ]
    env = build_env(open_evidence(plain).run)
    assert _stack(env) == ["TimeLimit", "CartPoleEnv"]
    assert env.spec is not None and env.spec.max_episode_steps == 7
    wrapped = tmp_path / "wrapped.mcap"
    with RecordEvidence(gym.wrappers.ClipReward(gym.make("CartPole-v1"), 0.0, 0.5), wrapped) as rec:
        rec.reset(seed=1)
        for _ in range(5):
            rec.step(0)
    assert _stack(build_env(open_evidence(wrapped).run)) == [
        "ClipReward",
        "TimeLimit",
        "CartPoleEnv",
    ]
    assert replay([plain, wrapped]).count("identical") == 3


def test_a_wrapper_of_another_gymnasium_is_named_not_replayed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A file made with a wrapper the installed Gymnasium lacks (ClipReward stands in for one
    a newer release added, e.g. 1.3's RepeatAction) says so, and which version is here."""
    wrapped = tmp_path / "wrapped.mcap"
    with RecordEvidence(gym.wrappers.ClipReward(gym.make("CartPole-v1"), 0.0, 0.5), wrapped) as rec:
        rec.reset(seed=1)
        rec.step(0)
    monkeypatch.delattr(gym.wrappers, "ClipReward")
    with pytest.raises(ReplayError, match=r"^the recorded wrapper ClipReward is not in this Gym"):
        build_env(open_evidence(wrapped).run)
    [episode] = replay([wrapped]).episodes
    assert episode.status == "not_replayable"
    assert f"is not in this Gymnasium ({gym.__version__}); replay with" in str(episode.reason)


def _reshaped() -> gym.Env[Any, Any]:
    return gym.wrappers.ReshapeObservation(gym.make("Pendulum-v1", max_episode_steps=4), (3, 1))


def _sticky() -> gym.Env[Any, Any]:
    return gym.wrappers.StickyAction(gym.make("CartPole-v1", max_episode_steps=4), 0.5, (1, 2))


@pytest.mark.parametrize("make", [_reshaped, _sticky], ids=["reshape", "sticky"])
def test_a_wrapper_argument_that_must_be_a_tuple_is_rebuilt_as_one(
    tmp_path: Path, make: Callable[[], gym.Env[Any, Any]]
) -> None:
    """The file holds the tuple as a JSON list; the wrapper refuses a list."""
    path = tmp_path / "t.mcap"
    with RecordEvidence(make(), path) as rec:
        for seed in (1, 2):
            rec.reset(seed=seed)
            rec.action_space.seed(seed)
            for _ in range(4):
                rec.step(rec.action_space.sample())
    assert [e.status for e in replay([path]).episodes] == ["identical"] * 2


@pytest.mark.parametrize("typed", [True, False], ids=["typed", "older-file"])
def test_a_registered_tuple_kwarg_is_rebuilt_as_the_registry_gives_it(
    tmp_path: Path, typed: bool
) -> None:
    """ALE's v0 / v4 ids register ``frameskip=(2, 5)``; the spec's JSON holds it as a list,
    which ALE refuses ("Invalid frameskip type"). A file of an older recorder, without the
    layout's ``spec_kwargs_typed``, takes the registered value."""
    ale_py = pytest.importorskip("ale_py")
    gym.register_envs(ale_py)
    path = tmp_path / "b.mcap"
    with RecordEvidence(gym.make("Breakout-v4", obs_type="ram", max_episode_steps=15), path) as rec:
        rec.action_space.seed(0)
        for seed in (1, 2):
            rec.reset(seed=seed)
            for _ in range(15):
                rec.step(rec.action_space.sample())
    if not typed:

        def older(meta: dict[str, str]) -> dict[str, str]:
            layout = json.loads(meta["layout"])
            del layout["spec_kwargs_typed"]
            return {**meta, "layout": json.dumps(layout)}

        path = rewrite(path, tmp_path / "older.mcap", run=older)
    run = open_evidence(path).run
    assert run.env_spec is not None and run.env_spec["kwargs"]["frameskip"] == [2, 5]
    assert ("spec_kwargs_typed" in run.layout) is typed
    assert [(e.status, e.reason) for e in replay([path]).episodes] == [("identical", None)] * 2


@pytest.mark.parametrize("vector", [False, True], ids=["single", "vector"])
def test_a_tuple_kwarg_given_to_make_is_rebuilt_as_one(tmp_path: Path, vector: bool) -> None:
    """``frameskip=(2, 5)`` given to ``gym.make``: the spec's JSON holds a list, which ALE
    refuses; the layout's ``spec_kwargs_typed`` holds the tuple."""
    ale_py = pytest.importorskip("ale_py")
    gym.register_envs(ale_py)
    path = tmp_path / "b.mcap"
    kwargs: dict[str, Any] = {"frameskip": (2, 5), "obs_type": "ram", "max_episode_steps": 15}
    if vector:
        envs = gym.make_vec("ALE/Breakout-v5", 2, vectorization_mode="sync", **kwargs)
        with RecordVectorEvidence(envs, path) as rec:
            rec.action_space.seed(0)
            rec.reset(seed=1)
            for _ in range(20):
                rec.step(rec.action_space.sample())
    else:
        with RecordEvidence(gym.make("ALE/Breakout-v5", **kwargs), path) as single:
            single.action_space.seed(0)
            for seed in (1, 2):
                single.reset(seed=seed)
                for _ in range(15):
                    single.step(single.action_space.sample())
    run = open_evidence(path).run
    assert run.env_spec is not None and run.env_spec["kwargs"]["frameskip"] == [2, 5]
    assert decode_typed(run.layout["spec_kwargs_typed"]) == {"frameskip": (2, 5)}
    replays = replay([path]).episodes
    assert [(e.status, e.reason) for e in replays] == [("identical", None)] * len(replays) != []


@pytest.mark.parametrize("dtype", [np.float32, np.dtype("float32")], ids=["type", "dtype"])
def test_a_dtype_observation_is_recorded_by_its_dtype_name_and_rebuilt(
    tmp_path: Path, dtype: Any
) -> None:
    try:
        gym.wrappers.DtypeObservation(gym.make("Pendulum-v1"), dtype).reset(seed=0)
    except TypeError:  # (Gymnasium 1.1 calls its dtype on each observation)
        pytest.skip("this Gymnasium's DtypeObservation takes no numpy.dtype")
    path = tmp_path / "d.mcap"
    pendulum = gym.make("Pendulum-v1", max_episode_steps=3)
    with RecordEvidence(gym.wrappers.DtypeObservation(pendulum, dtype), path) as rec:
        rec.reset(seed=1)
        for _ in range(3):
            rec.step(np.array([0.5], np.float32))
    run = open_evidence(path).run
    assert run.env_spec is not None
    assert run.env_spec["additional_wrappers"][-1]["kwargs"] == {"dtype": "float32"}
    assert [e.status for e in replay([path]).episodes] == ["identical"]


def test_a_recorded_wrapper_that_cannot_be_rebuilt_is_named_not_the_env(tmp_path: Path) -> None:
    """A file whose ReshapeObservation shape (hand-edited) does not fit Pendulum's 3 values."""
    recorded = tmp_path / "r.mcap"
    with RecordEvidence(_reshaped(), recorded) as rec:
        rec.reset(seed=1)
        rec.step(rec.action_space.sample())

    def run(meta: dict[str, str]) -> dict[str, str]:
        spec = json.loads(meta["env_spec"])
        spec["additional_wrappers"][-1]["kwargs"]["shape"] = [2, 2]
        return {**meta, "env_spec": json.dumps(spec)}

    path = rewrite(recorded, tmp_path / "edited.mcap", run=run)
    [episode] = replay([path]).episodes
    assert episode.status == "not_replayable"
    assert episode.reason is not None and episode.reason.startswith(
        "cannot rebuild the recorded wrapper ReshapeObservation with its recorded arguments "
        '{"shape": [2, 2]}: '
    ), episode.reason  # (ValueError; AssertionError in Gymnasium 1.1)
    assert episode.reason.endswith("; pass --env-factory MODULE:CALLABLE that builds the env")


def _limit_script(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
    """Action 1 ends the task, 2 makes the env truncate itself; stepping past ``env.fail_at``
    steps raises."""
    if env.t > getattr(env, "fail_at", 10**9):
        raise RuntimeError("the env broke")
    obs = np.full(2, env.t / 10, np.float32)
    return obs, float(env.t), action == 1, action == 2, {}


def _limited(limit: int, fail_at: int | None = None) -> gym.wrappers.TimeLimit[Any, Any]:
    env = ScriptedEnv(_limit_script)
    if fail_at is not None:
        env.fail_at = fail_at  # type: ignore[attr-defined]
    return gym.wrappers.TimeLimit(env, limit)


# (actions per episode) recorded behind a TimeLimit of 4: a limit truncation, both flags on
# the limit-th step, the env's own truncation and a termination before the limit
_LIMIT_EPISODES = [[0, 0, 0, 0], [0, 0, 0, 1], [0, 2], [0, 1], [1]]


@pytest.mark.parametrize(
    ("limit", "fail_at", "statuses"),
    [
        (4, None, ["identical"] * 5),
        (3, None, ["not_replayable", "not_replayable", "identical", "identical", "identical"]),
        (5, None, ["not_replayable", "not_replayable", "identical", "identical", "identical"]),
        (4, 3, ["not_replayable", "not_replayable", "identical", "identical", "identical"]),
    ],
)
def test_an_outermost_time_limit_is_counted_by_replay_exactly_as_the_wrapper_would(
    tmp_path: Path, limit: int, fail_at: int | None, statuses: list[str]
) -> None:
    """Replay steps the env inside a plain TimeLimit and counts the limit itself; every
    result, divergence included, is the one the wrapper's own step gives (the file has no spec
    to verify the factory's env against: a difference is not the env's divergence). A limit
    other than the recorded one ends episodes elsewhere: limits that differ."""
    path = tmp_path / "limit.mcap"
    with RecordEvidence(_limited(4), path) as rec:
        for e, actions in enumerate(_LIMIT_EPISODES):
            rec.reset(seed=e)
            for action in actions:
                rec.step(action)
    made: list[gym.wrappers.TimeLimit[Any, Any]] = []

    def counted() -> gym.Env[Any, Any]:
        made.append(_limited(limit, fail_at))
        return made[-1]

    def called() -> gym.Env[Any, Any]:  # an outer wrapper: the TimeLimit's step is called
        return gym.Wrapper(_limited(limit, fail_at))

    assert plain_time_limit(counted()) is not None and plain_time_limit(called()) is None
    by_count = replay([path], env_factory=counted).episodes
    by_call = replay([path], env_factory=called).episodes
    assert by_count == by_call
    assert [e.status for e in by_count] == statuses
    assert made[-1]._elapsed_steps is None  # the wrapper itself never ran
    if limit == 3:
        divergence = by_count[0].divergence
        assert divergence is not None and (divergence.step, divergence.field) == (2, "truncated")
        assert by_count[0].reason == (
            "the rebuilt env's time limit truncated it at step 2, where the recorded episode "
            "went on: the rebuilt env's TimeLimits are not those it was recorded in (a limit set "
            "after the recorder was made, say); build it with the limits it ran under"
        )
    if limit == 5:
        assert (by_count[0].reason or "").startswith(
            "recorded truncated by its time limit at step 3, where the rebuilt env's limits were "
            "not reached: "
        )


def test_load_callable_errors() -> None:
    with pytest.raises(ConfigurationError, match="expected MODULE:CALLABLE"):
        load_callable("nocolon")
    with pytest.raises(ConfigurationError, match="cannot load 'no_such_module_xyz:f'"):
        load_callable("no_such_module_xyz:f")


def test_a_factory_module_in_the_current_folder_is_found_by_the_command(tmp_path: Path) -> None:
    # the console script's sys.path has no current folder (python -m and pytest add it)
    path = record_random(tmp_path / "cp.mcap", "CartPole-v1", 2)
    (tmp_path / "beside.py").write_text(
        "import gymnasium as gym\n\ndef make():\n    return gym.make('CartPole-v1')\n"
    )
    command = Path(sys.executable).with_name("episode-audit")
    done = subprocess.run(
        [str(command), "replay", str(path), "--env-factory", "beside:make"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert "2 identical" in done.stdout
    done = subprocess.run(
        [str(command), "replay", str(path), "--env-factory", "beside_not:make"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2 and done.stderr.startswith(
        "episode-audit: error: cannot load 'beside_not:make': No module named 'beside_not'"
    ), done.stderr


def test_replay_in_a_fresh_process(tmp_path: Path) -> None:
    path = record_random(tmp_path / "cp.mcap", "CartPole-v1", 4)
    script = textwrap.dedent(
        f"""
        from episode_audit.replay import replay
        r = replay([{str(path)!r}])
        assert r.count("identical") == 4, r
        """
    )
    subprocess.run([sys.executable, "-c", script], check=True, cwd=REPO)


def test_outcomes_replay_per_episode_when_endings_alternate(tmp_path: Path) -> None:
    """A time-limit truncation followed by a termination: each outcome is judged on its own."""
    path = tmp_path / "mixed.mcap"
    outcomes: list[str] = []
    with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=12), path) as env:
        env.action_space.seed(3)
        for e in range(60):
            env.reset(seed=e)
            done = False
            while not done:
                _, _, term, trunc, _ = env.step(env.action_space.sample())
                done = term or trunc
            outcomes.append("truncated" if trunc and not term else "failure")
            if "truncated" in outcomes and outcomes[-1] == "failure" and len(outcomes) > 2:
                break
    assert "truncated" in outcomes[:-1] and outcomes[-1] == "failure"
    result = replay([path])
    assert result.ok, [e for e in result.episodes if e.status != "identical"]


@pytest.mark.parametrize("window", [1, 7, 50])
def test_replay_streams_in_windows_of_whole_episodes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, window: int
) -> None:
    # the package exports the function `replay`; the module is reached through sys.modules
    replay_module = sys.modules["episode_audit.replay.single"]

    path = tmp_path / "cp.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path, block_steps=16) as env:
        env.action_space.seed(0)
        for e in range(12):
            env.reset(seed=e)
            done = False
            while not done:
                _, _, term, trunc, _ = env.step(env.action_space.sample())
                done = term or trunc
        env.reset(seed=99)  # an episode with no steps: closed as incomplete
    monkeypatch.setattr(replay_module, "REPLAY_WINDOW_ROWS", window)
    result = replay([path])
    assert [e.episode for e in result.episodes] == list(range(12)) and result.unstarted == 1
    assert result.count("identical") == 12, [e for e in result.episodes if e.status != "identical"]
    assert replay([path], episodes=[3, 11]).count("identical") == 2


@pytest.mark.parametrize(("window", "passes"), [(10**6, 1), (40, 2)])
def test_replay_reads_a_file_once_when_it_fits_one_window(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, window: int, passes: int
) -> None:
    from episode_audit.read import chunks as chunks_module

    replay_module = sys.modules["episode_audit.replay.single"]
    path = tmp_path / "cp.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path, block_steps=16) as env:
        env.action_space.seed(0)
        for e in range(8):
            env.reset(seed=e)
            done = False
            while not done:
                _, _, term, trunc, _ = env.step(env.action_space.sample())
                done = term or trunc
    reads: list[int] = []
    original = chunks_module._read_chunk_record

    def counting(f: Any, ref: Any, where: Path) -> Any:
        reads.append(ref.offset)
        return original(f, ref, where)

    monkeypatch.setattr(chunks_module, "_read_chunk_record", counting)
    monkeypatch.setattr(replay_module, "REPLAY_WINDOW_ROWS", window)
    assert replay([path]).count("identical") == 8
    chunks = len(set(reads))
    assert chunks > 3
    if passes == 1:
        assert len(reads) == chunks
    else:  # the episodes table first: only the chunks with reset blocks or episode records
        assert chunks < len(reads) < passes * chunks


def pixel_cartpole(heavier: bool = False) -> gym.Env[Any, Any]:
    """CartPole whose observation is its rendered frame (400 x 600 x 3 bytes, 720 kB)."""
    pytest.importorskip("pygame")
    env = (
        make_heavier_cartpole(render_mode="rgb_array")
        if heavier
        else gym.make("CartPole-v1", render_mode="rgb_array")
    )
    return gym.wrappers.AddRenderObservation(env, render_only=True)


def test_camera_frames_replay_in_windows_of_bounded_bytes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A window of 65 536 rows of camera frames is 47 GB: replay windows are bounded by bytes
    # too (whole episodes, at least one), and compares frames in passes of a few rows.
    replay_module = sys.modules["episode_audit.replay.single"]
    path = tmp_path / "pixels.mcap"
    with RecordEvidence(pixel_cartpole(), path, block_steps=4) as env:
        for e in range(4):
            env.reset(seed=e)
            for t in range(500):
                _, _, term, trunc, _ = env.step(t % 2)
                if term or trunc:
                    break
    windows: list[int] = []
    runner_module = sys.modules["episode_audit.replay.runner"]
    run_all = runner_module.EpisodeRunner.run_all

    def counting(self: Any, records: Any, steps: pa.Table, *args: Any) -> Any:
        windows.append(steps.num_rows)
        return run_all(self, records, steps, *args)

    monkeypatch.setattr(runner_module.EpisodeRunner, "run_all", counting)
    monkeypatch.setattr(replay_module, "REPLAY_WINDOW_BYTES", 4 * 720_000)
    result = replay([path], env_factory=pixel_cartpole)
    assert result.count("identical") == 4, result.episodes
    assert len(windows) == 4 and sum(windows) == sum(e.steps for e in result.episodes)

    changed = replay([path], env_factory=lambda: pixel_cartpole(heavier=True)).episodes
    assert [e.status for e in changed] == ["diverged"] * 4
    first = changed[0].divergence
    assert first is not None and first.field == "observation" and first.step is not None
    assert first.max_abs_diff is not None and 0 < first.max_abs_diff <= 255
    # a frame is too long to show: the first differing pixel is named
    assert first.first_difference is not None
    assert re.fullmatch(
        r"\[\d+, \d+, [012]\]: expected \d+, got \d+; \d+ of 720000 elements differ",
        first.first_difference,
    ), first.first_difference
    assert f"first at {first.first_difference}" in first.describe()
    assert len(first.expected) <= 80


class Counter(gym.Env[Any, int]):
    """Counts up by its action; hands out one observation array it changes in place."""

    observation_space = gym.spaces.Box(-1000.0, 1000.0, (2,), np.float64)
    action_space = gym.spaces.Discrete(3)

    def __init__(self, length: int = 6, raise_at: int | None = None) -> None:
        self.length, self.raise_at = length, raise_at
        self.buffer = np.zeros(2)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        super().reset(seed=seed)
        self.t = 0
        self.buffer[:] = self.np_random.integers(0, 10), 0.0
        return self.buffer, {}

    def step(self, action: int) -> Any:
        self.t += 1
        if self.t == self.raise_at:
            raise RuntimeError("boom")
        self.buffer += (int(action), 1.0)  # the same array, changed in place
        terms = {"reward_terms": {"count": float(action), "alive": 1.0}}
        return self.buffer, float(action) + 1.0, self.t >= self.length, False, terms


def record_counter(path: Path, episodes: int = 4) -> Path:
    with RecordEvidence(Counter(), path) as env:
        env.action_space.seed(5)
        for e in range(episodes):
            env.reset(seed=e)
            done = False
            while not done:
                _, _, term, trunc, _ = env.step(env.action_space.sample())
                done = term or trunc
    return path


def test_an_env_that_reuses_its_observation_array_replays_identically(tmp_path: Path) -> None:
    path = record_counter(tmp_path / "counter.mcap")
    result = replay([path], env_factory=Counter)
    assert result.count("identical") == 4, result.episodes
    assert [e.steps for e in result.episodes] == [6] * 4


def test_an_episode_that_ends_early_on_replay_diverges_on_its_flag(tmp_path: Path) -> None:
    path = record_counter(tmp_path / "counter.mcap", episodes=2)
    result = replay([path], env_factory=lambda: Counter(length=4))
    assert [(e.status, e.steps) for e in result.episodes] == [("not_replayable", 3)] * 2
    divergence = result.episodes[1].divergence
    assert divergence is not None
    assert divergence.describe() == "step 3: terminated expected False, got True"


def test_an_env_that_raises_on_replay_diverges_at_that_step(tmp_path: Path) -> None:
    path = record_counter(tmp_path / "counter.mcap", episodes=3)
    result = replay([path], env_factory=lambda: Counter(raise_at=3))
    for episode in result.episodes:
        assert episode.status == "not_replayable" and episode.steps == 2  # (no spec: unverified)
        assert episode.divergence is not None
        assert (episode.divergence.step, episode.divergence.field) == (2, "step")
        assert episode.divergence.got == "RuntimeError: boom"


def test_a_changed_reward_term_diverges_on_terms(tmp_path: Path) -> None:
    class Renamed(Counter):
        def step(self, action: int) -> Any:
            obs, reward, term, trunc, _ = super().step(action)
            renamed = {"reward_terms": {"count": float(action), "alive!": 1.0}}
            return obs, reward, term, trunc, renamed

    path = record_counter(tmp_path / "counter.mcap", episodes=1)
    result = replay([path], env_factory=Renamed)
    divergence = result.episodes[0].divergence
    assert divergence is not None and (divergence.step, divergence.field) == (0, "terms")
    assert "'alive!': 1.0" in divergence.got


class Shapeshifter(Counter):
    """Hands out its observations as lists, float32 arrays and views, by turns."""

    def step(self, action: int) -> Any:
        obs, *rest = super().step(action)
        kind = self.t % 5
        if kind == 1:
            obs = obs.tolist()
        elif kind == 2:
            obs = obs.astype(np.float32)
        elif kind == 3:
            obs = np.stack([obs, obs])[0]  # a view of a bigger array
        elif kind == 4:  # the space's dtype and shape, but not C-contiguous
            obs = np.stack([obs, obs], axis=1)[:, 0]
            assert obs.shape == (2,) and not obs.flags.c_contiguous
        return (obs, *rest)


def test_observations_of_any_form_replay_identically(tmp_path: Path) -> None:
    """Rows that are not exactly the space's dtype and shape go through the column buffer."""
    path = tmp_path / "shapes.mcap"
    with RecordEvidence(Shapeshifter(), path) as env:
        for e in range(3):
            env.reset(seed=e)
            for action in (1, 2, 0, 1, 2, 1):
                env.step(action)

    class Plainly(Shapeshifter):
        step = Counter.step

    for factory in (Shapeshifter, Plainly):  # recorded by turns, replayed by turns or not
        result = replay([path], env_factory=factory)
        assert result.count("identical") == 3, result.episodes


def test_an_observation_that_cannot_be_encoded_diverges_at_its_step(tmp_path: Path) -> None:
    class Garbled(Counter):
        def step(self, action: int) -> Any:
            obs, *rest = super().step(action)
            return ("not an array" if self.t == 4 else obs, *rest)

    path = record_counter(tmp_path / "counter.mcap", episodes=2)
    result = replay([path], env_factory=Garbled)
    for episode in result.episodes:
        assert episode.divergence is not None
        assert (episode.divergence.step, episode.divergence.field) == (3, "observation")
        assert episode.divergence.got == "None"


def test_every_episode_whose_outcome_changed_diverges_on_it(tmp_path: Path) -> None:
    """The same flags and info in every episode: the outcome is classified once, compared
    with each episode's record."""

    class Labelled(Counter):
        def step(self, action: int) -> Any:
            obs, reward, term, trunc, _ = super().step(action)
            return obs, reward, term, trunc, {"failure": "fell"} if term else {}

    class Plain(Labelled):
        def step(self, action: int) -> Any:
            obs, reward, term, trunc, _ = super().step(action)
            return obs, reward, term, trunc, {}

    path = tmp_path / "labelled.mcap"
    with RecordEvidence(Labelled(), path) as env:
        for e in range(3):
            env.reset(seed=e)
            done = False
            while not done:
                _, _, term, trunc, _ = env.step(1)
                done = term or trunc
    assert replay([path], env_factory=Labelled).count("identical") == 3
    result = replay([path], env_factory=Plain)  # (no spec: a difference is unverified)
    assert [e.status for e in result.episodes] == ["not_replayable"] * 3
    for episode in result.episodes:
        assert episode.divergence is not None
        assert episode.divergence.describe() == (
            "step 5: outcome expected failure/fell, got failure/unlabeled"
        )


def test_rewards_that_are_not_numbers_become_nan() -> None:
    got, refused = _rewards([1, 10**400, "2.0", np.float32(0.5), True])
    assert [got[0], got[3], got[4]] == [1.0, 0.5, 1.0]
    assert math.isnan(got[1]) and math.isnan(got[2])
    assert refused == {
        1: "OverflowError: int too large to convert to float",
        2: "TypeError: must be real number, not str",
    }
    # an array of one element is no number with any numpy (as the recorder reads it); 0-d is
    got, refused = _rewards([np.array([1.5]), np.array(2.0), 3.0])
    assert math.isnan(got[0]) and list(got[1:]) == [2.0, 3.0]
    assert refused == {0: "TypeError: an array of shape (1,) is not a number"}


def test_a_reward_of_one_element_arrays_replays_identically(tmp_path: Path) -> None:
    """Recorded as NaN (noted), and replay reads the re-run env's the same way."""
    path = tmp_path / "array.mcap"
    with RecordEvidence(ArrayReward(), path) as env:
        for seed in range(2):
            env.reset(seed=seed)
            for _ in range(3):
                env.step(1)
    rewards = open_evidence(path).steps().column("reward").to_pylist()
    assert len(rewards) == 6 and all(math.isnan(r) for r in rewards)
    result = replay([path], env_factory=ArrayReward)
    assert [(e.status, e.steps) for e in result.episodes] == [("identical", 3)] * 2, result


class ArrayReward(gym.Env[Any, int]):
    """Its rewards are arrays of one element (``np.array([1.0])``)."""

    observation_space = gym.spaces.Box(-10.0, 10.0, (1,), np.float64)
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(1), {}

    def step(self, action: int) -> Any:
        self.t += 1
        return np.full(1, float(self.t)), np.array([1.0]), self.t == 3, False, {}


class PrefixTerms(Counter):
    """Terms as MuJoCo v5 envs give them: ``reward_*`` keys of the info."""

    alive = 1.0

    def step(self, action: int) -> Any:
        obs, reward, term, trunc, _ = super().step(action)
        info = {"reward_count": float(action), "x": 0, "reward_alive": self.alive}
        return obs, reward, term, trunc, info


def test_prefix_terms_replay_identically_and_diverge_by_name(tmp_path: Path) -> None:
    path = tmp_path / "prefix.mcap"
    with RecordEvidence(PrefixTerms(), path) as env:
        env.action_space.seed(2)
        for e in range(3):
            env.reset(seed=e)
            for _ in range(6):
                env.step(env.action_space.sample())
    assert replay([path], env_factory=PrefixTerms).count("identical") == 3

    class Cheaper(PrefixTerms):
        alive = 0.5

    divergence = replay([path], env_factory=Cheaper).episodes[2].divergence
    assert divergence is not None and (divergence.step, divergence.field) == (0, "terms")
    assert divergence.got == "{'reward_count': 2.0, 'reward_alive': 0.5}"
    assert divergence.expected == "{'reward_count': 2.0, 'reward_alive': 1.0}"


# --------------------------------------------------------------------------------------------
# terms comparison over whole columns
# --------------------------------------------------------------------------------------------

_NAMES = st.sampled_from(["a", "b", "ctrl", "é"])
_VALUES = st.one_of(
    st.sampled_from([0.0, -0.0, 1.0, 1.5, math.nan, math.inf, None]),
    st.floats(-2, 2, allow_nan=False),
)
_ROW = st.one_of(st.none(), st.lists(st.tuples(_NAMES, _VALUES), max_size=3))


@given(
    pairs=st.lists(st.tuples(_ROW, _ROW), max_size=12),
    atol=st.sampled_from([0.0, 1e-9, 0.5]),
    cut=st.integers(0, 3),
)
@settings(max_examples=300, deadline=None)
def test_terms_rows_equal_agrees_with_the_row_by_row_rule(
    pairs: list[tuple[Any, Any]], atol: float, cut: int
) -> None:
    # the same two columns sliced (offsets into longer children), as take() may leave them
    pad = [[("pad", 1.0)]] * cut
    exp = pa.array(pad + [a for a, _ in pairs], TERMS_TYPE).slice(cut)
    got = pa.array(pad + [b for _, b in pairs], TERMS_TYPE).slice(cut)
    # the row-by-row rule (PettingZoo replay's) is the reference
    expected = [_terms_equal(a, b, atol) for a, b in pairs]
    assert _terms_rows_equal(exp, got, atol).tolist() == expected


@pytest.mark.parametrize(
    ("a", "b", "atol", "equal"),
    [
        (None, None, 0.0, True),
        (None, [], 0.0, False),
        ([], [], 0.0, True),
        ([("a", 1.0)], [("a", 1.0)], 0.0, True),
        ([("a", math.nan)], [("a", math.nan)], 0.0, True),
        ([("a", 1.0)], [("a", 1.0 + 1e-12)], 0.0, False),
        ([("a", 1.0)], [("a", 1.0 + 1e-12)], 1e-9, True),
        ([("a", 1.0), ("b", 2.0)], [("b", 2.0), ("a", 1.0)], 0.0, False),  # order counts
        ([("a", None)], [("a", None)], 0.5, True),
        ([("a", None)], [("a", 0.0)], 0.5, False),
    ],
)
def test_terms_equal_rule(a: Any, b: Any, atol: float, equal: bool) -> None:
    assert _terms_equal(a, b, atol) is equal


def test_row_ranges_of_runs_of_episodes() -> None:
    assert _row_ranges(np.array([3, 3, 5, 5, 5, 7])) == {3: (0, 2), 5: (2, 3), 7: (5, 1)}
    assert _row_ranges(np.array([1, 1, 2, 1])) == {1: (0, 2), 2: (2, 1)}  # the first run
    assert _row_ranges(np.array([], dtype=np.int64)) == {}


# --------------------------------------------------------------------------------------------
# infos that are not a dict of numbers: replay reads them as the recorder did, never raises
# --------------------------------------------------------------------------------------------

_BAD_INFOS: dict[str, Callable[[int], Any]] = {
    "list": lambda t: [1, 2],
    "str": lambda t: "info",
    "number": lambda t: 7,  # not even iterable
    "array": lambda t: np.array([1.0, 2.0]),  # no truth value
    "terms_list": lambda t: {"reward_terms": [0.5, 0.5]},
    "terms_scalar": lambda t: {"reward_terms": 0.5},
    "terms_array": lambda t: {"reward_terms": {"a": np.array([1.0])}, "reward_x": np.zeros(2)},
    "prefix_array": lambda t: {"reward_x": np.zeros(2), "reward_y": 1.0},
    "prefix_surrogate": lambda t: {"reward_\udcff": 1.0},  # not UTF-8: written escaped
    "terms_int_names": lambda t: {"reward_terms": {0: 0.5, 1: 0.5}},
    "terms_text": lambda t: {"reward_terms": {"a": "1.5", "b": 0.5}},
    "by_turns": lambda t: [{"reward_terms": {"a": 0.5}}, [1], {"reward_terms": {0: t}}, "x"][t - 1],
    "success_array": lambda t: {"success": np.array([True, False])},  # ends by its flags
}
_NAN = math.nan
# the terms the recorder wrote for the first episode's four steps (compared by repr: NaN)
_RECORDED_TERMS: dict[str, list[Any]] = {
    "list": [None] * 4,
    "str": [None] * 4,
    "number": [None] * 4,
    "array": [None] * 4,
    "terms_list": [None] * 4,
    "terms_scalar": [None] * 4,
    "terms_array": [[("a", _NAN)]] * 4,
    "prefix_array": [[("reward_x", _NAN), ("reward_y", 1.0)]] * 4,
    "prefix_surrogate": [[("reward_\\udcff", 1.0)]] * 4,
    "terms_int_names": [[("0", 0.5), ("1", 0.5)]] * 4,
    "terms_text": [[("a", _NAN), ("b", 0.5)]] * 4,
    "by_turns": [[("a", 0.5)], None, [("0", 3.0)], None],
    "success_array": [None] * 4,
}


class BadInfo(gym.Env[Any, int]):
    """Deterministic; its info, per ``kind``, is one the recorder notes (or reads) and records."""

    observation_space = gym.spaces.Box(-10.0, 10.0, (2,), np.float64)
    action_space = gym.spaces.Discrete(2)

    def __init__(self, kind: str) -> None:
        self.kind = kind

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        super().reset(seed=seed)
        self.t = 0
        return np.array([self.np_random.integers(0, 5), 0.0]), {}

    def step(self, action: int) -> Any:
        self.t += 1
        obs = np.array([float(action), float(self.t)])
        return obs, 1.0, self.t == 4, False, _BAD_INFOS[self.kind](self.t)


def bad_info_list() -> BadInfo:
    """The --env-factory of the CLI test."""
    return BadInfo("list")


def record_bad_info(path: Path, kind: str) -> Path:
    with RecordEvidence(BadInfo(kind), path) as env:
        env.action_space.seed(1)
        for e in range(3):
            env.reset(seed=e)
            for _ in range(4):
                env.step(env.action_space.sample())
    return path


@pytest.mark.parametrize("kind", list(_BAD_INFOS))
def test_an_info_the_recorder_tolerated_replays_identically(tmp_path: Path, kind: str) -> None:
    """Not a dict, terms that cannot be read, a term that is not a number (NaN, which equals
    NaN), a name that is not a string (str()-ed): replay reads the re-run env's infos so."""
    path = record_bad_info(tmp_path / "bad.mcap", kind)
    recorded = open_evidence(path).steps().column("terms").to_pylist()[:4]
    assert repr(recorded) == repr(_RECORDED_TERMS[kind])
    result = replay([path], env_factory=lambda: BadInfo(kind))
    assert [(e.status, e.steps) for e in result.episodes] == [("identical", 4)] * 3, result


def test_terms_read_info_by_info_still_diverge_on_a_changed_value(tmp_path: Path) -> None:
    class Retuned(BadInfo):
        def step(self, action: int) -> Any:
            obs, reward, term, trunc, info = super().step(action)
            return obs, reward, term, trunc, {"reward_terms": {0: 4.0}} if self.t == 3 else info

    path = record_bad_info(tmp_path / "bad.mcap", "by_turns")
    result = replay([path], env_factory=lambda: Retuned("by_turns"))
    assert [(e.status, e.steps) for e in result.episodes] == [("not_replayable", 2)] * 3
    divergence = result.episodes[0].divergence
    assert divergence is not None
    assert divergence.describe() == "step 2: terms expected {'0': 3.0}, got {'0': 4.0}"


# --------------------------------------------------------------------------------------------
# a file without its env spec: replayable only in an env the user builds
# --------------------------------------------------------------------------------------------


class _ClassEntry(gym.Env[Any, Any]):
    """An env registered with its class as the entry point (``gym.register(id, entry_point=C)``)."""

    observation_space = gym.spaces.Box(-10.0, 10.0, (2,), np.float32)
    action_space = gym.spaces.Discrete(2)

    def __init__(self, step: float = 0.1) -> None:
        self.size = step

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        super().reset(seed=seed)
        self.p = self.np_random.uniform(-1, 1, 2).astype(np.float32)
        return self.p, {}

    def step(self, action: Any) -> Any:
        self.p = (self.p + (self.size if action else -self.size)).astype(np.float32)
        return self.p, float(self.p.sum()), False, False, {}


def test_an_env_registered_with_a_class_as_entry_point_replays(tmp_path: Path) -> None:
    gym.register("ClassEntry-v0", entry_point=_ClassEntry, max_episode_steps=4)
    try:
        path = tmp_path / "class.mcap"
        with RecordEvidence(gym.make("ClassEntry-v0", step=0.5), path) as env:
            for e in range(2):
                env.reset(seed=e)
                for _ in range(4):
                    env.step(e % 2)
        spec = open_evidence(path).run.env_spec
        assert spec is not None
        assert spec["entry_point"] == f"{__name__}:_ClassEntry"
        assert spec["kwargs"] == {"step": 0.5}
        assert replay([path]).count("identical") == 2
    finally:
        del gym.registry["ClassEntry-v0"]


_WRAPPER_FUNCTION = (
    "the recorded wrapper TransformReward: its argument func is a function, which a file cannot "
    "hold; pass --env-factory MODULE:CALLABLE that builds the env"
)  # (not --trust-entry-points: the function is not in the file, so it refuses too)
_PLACEHOLDER = (
    "the recorded TransformReward argument 'func' is not in the file (function "
    f"{__name__}:doubled_cartpole.<locals>.<lambda>: JSON cannot hold it); pass --env-factory "
    "MODULE:CALLABLE that builds the env"
)


def doubled_cartpole() -> gym.Env[Any, Any]:
    """CartPole whose rewards are doubled by a lambda, which JSON cannot hold."""
    return gym.wrappers.TransformReward(gym.make("CartPole-v1"), lambda r: 2 * r)


def record_doubled(path: Path) -> Path:
    with RecordEvidence(doubled_cartpole(), path) as env:
        for e in range(2):
            env.reset(seed=e)
            for _ in range(5):
                env.step(e % 2)
    return path


def test_a_wrapper_given_a_function_is_replayed_only_with_an_env_factory(tmp_path: Path) -> None:
    """The spec keeps a placeholder for the function: the id, the time limit and the wrapper
    are in the file; built without the wrapper, CartPole would pay 1.0 where 2.0 was recorded
    (a false divergence), so replay refuses, trusted or not."""
    path = record_doubled(tmp_path / "doubled.mcap")
    run = open_evidence(path).run
    assert run.env_id == "CartPole-v1" and run.env_spec is not None
    assert run.env_spec["max_episode_steps"] == 500
    (wrapper,) = run.env_spec["additional_wrappers"]
    assert wrapper["kwargs"] == {
        "func": {
            "episode_audit.unrecorded": f"function {__name__}:doubled_cartpole.<locals>.<lambda>"
        }
    }
    for trust, why in ((False, _WRAPPER_FUNCTION), (True, _PLACEHOLDER)):
        result = replay([path], trust_entry_points=trust)
        assert [(e.status, e.steps) for e in result.episodes] == [("not_replayable", 0)] * 2
        assert [e.reason for e in result.episodes] == [why] * 2
    with pytest.raises(ReplayError, match=re.escape(_WRAPPER_FUNCTION)):
        build_env(run)
    assert replay([path], env_factory=doubled_cartpole).count("identical") == 2


# --------------------------------------------------------------------------------------------
# the CLI: exit 0 for identical, 1 for a divergence or when no episode could be verified
# --------------------------------------------------------------------------------------------


def _cli(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, list(args))
    if result.exception and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout


def test_cli_replays_an_info_the_recorder_tolerated_and_exits_0(tmp_path: Path) -> None:
    path = record_bad_info(tmp_path / "bad.mcap", "list")
    code, out = _cli("replay", str(path), "--env-factory", "tests.replay.test_replay:bad_info_list")
    assert code == 0, out
    assert "3 identical, 0 diverged, 0 not replayable" in out


def test_cli_says_why_a_file_whose_wrapper_took_a_function_is_not_replayable_and_exits_1(
    tmp_path: Path,
) -> None:
    path = record_doubled(tmp_path / "doubled.mcap")
    result = CliRunner().invoke(app, ["replay", str(path), "--format", "json"])
    assert result.exit_code == 1, result.output  # nothing was verified
    data = json.loads(result.stdout)
    assert data["summary"] == {
        "verified": 0,
        "identical": 0,
        "diverged": 0,
        "not_replayable": 2,
        "unstarted": 0,
    }
    assert data["episodes"][0]["reason"] == _WRAPPER_FUNCTION
    assert result.stderr == (
        "episode-audit: error: replay verified no episode: all 2 episode(s) are not replayable "
        "(the output says why); pass --allow-unverified when that is expected\n"
    )
    code, out = _cli("replay", str(path), "--allow-unverified")
    assert code == 0, out
    assert out.strip().endswith("0 identical, 0 diverged, 2 not replayable: 0 episode(s) verified")
    code, out = _cli(
        "replay", str(path), "--env-factory", "tests.replay.test_replay:doubled_cartpole"
    )
    assert code == 0, out
    assert "2 identical, 0 diverged, 0 not replayable: 2 episode(s) verified" in out


def test_the_result_counts_the_episodes_verified(tmp_path: Path) -> None:
    path = record_doubled(tmp_path / "doubled.mcap")
    unverified = replay([path])
    assert not unverified.ok and unverified.verified == 0  # (nothing confirmed: not ok)
    assert unverified.count("diverged") == 0
    assert not replay([]).ok
    verified = replay([path], env_factory=doubled_cartpole)
    assert verified.verified == verified.count("identical") == 2
    assert verified.to_dict()["summary"]["verified"] == 2


def test_a_library_installed_but_not_imported_is_not_called_missing() -> None:
    """Replay's "current" version of a library the replaying process never imported."""
    from episode_audit.replay.run import _installed_version

    assert _installed_version("numpy") == np.__version__
    assert _installed_version("no-such-distribution-xyz") == "not installed"


class OddFlags(gym.Env[Any, int]):
    """Deterministic; a flag with no truth value (an array) on step 2, then ends on step 4;
    and a reset that raises for seed 99."""

    observation_space = gym.spaces.Box(-10.0, 10.0, (2,), np.float64)
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        super().reset(seed=seed)
        if seed == 99:
            raise RuntimeError("no level")
        self.t = 0
        return np.zeros(2), {}

    def step(self, action: int) -> Any:
        self.t += 1
        flag: Any = np.array([True, False]) if self.t == 2 else self.t == 4
        return np.array([float(action), float(self.t)]), 1.0, flag, False, {}


def test_odd_flags_replay_as_recorded_and_a_reset_error_says_so(tmp_path: Path) -> None:
    path = tmp_path / "flags.mcap"
    with RecordEvidence(OddFlags(), path) as env:
        env.reset(seed=0)
        for _ in range(4):
            env.step(0)
        with pytest.raises(RuntimeError, match="no level"):
            env.reset(seed=99)
    result = replay([path], env_factory=OddFlags)
    assert [(e.status, e.reason) for e in result.episodes] == [
        ("identical", None),
        ("not_replayable", "its reset raised (an error episode): there is no reset to compare"),
    ]


def _shifted_reset() -> gym.Env[Any, Any]:
    """CartPole whose reset observation is moved by 0.25 in its first element (its spec, with
    no wrapper saying so, as recorded)."""
    env = gym.make("CartPole-v1")
    cartpole: Any = env.unwrapped
    reset = cartpole.reset

    def shifted(**kwargs: Any) -> Any:
        obs, info = reset(**kwargs)
        return obs + np.array([0.25, 0, 0, 0], dtype=obs.dtype), info

    cartpole.reset = shifted
    return env


def test_a_reset_divergence_shows_both_observations(tmp_path: Path) -> None:
    """It said "got a different one": the replayed observation is what a user needs to see."""
    path = record_random(tmp_path / "cp.mcap", "CartPole-v1", 1)
    result = replay([path], env_factory=_shifted_reset)
    (episode,) = result.episodes
    divergence = episode.divergence
    assert divergence is not None and divergence.field == "reset_observation"
    expected = open_evidence(path).resets().column("observation")[0].as_py()
    assert divergence.max_abs_diff == pytest.approx(0.25, abs=1e-6)
    first = float(divergence.got.lstrip("[").split(",")[0])
    assert first == pytest.approx(expected[0] + 0.25, abs=1e-6), divergence.got
    assert float(divergence.expected.lstrip("[").split(",")[0]) == pytest.approx(expected[0])


class _Labelled(gym.Env[Any, Any]):
    """A Dict observation: a number (``x``) and a text label (``label``)."""

    observation_space = gym.spaces.Dict(
        {"x": gym.spaces.Box(-5, 5, (2,), np.float64), "label": gym.spaces.Text(4)}
    )
    action_space = gym.spaces.Discrete(2)

    def __init__(self, label: str = "a", x: float = 0.0) -> None:
        self.label, self.x = label, x

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        super().reset(seed=seed)
        return {"x": np.array([self.x, 0.0]), "label": self.label}, {}

    def step(self, action: Any) -> Any:
        return {"x": np.zeros(2), "label": "a"}, 0.0, True, False, {}


@pytest.mark.parametrize(("x", "max_abs_diff"), [(0.0, None), (0.25, 0.25)])
def test_max_abs_diff_of_a_dict_observation_is_its_numbers_not_its_text(
    tmp_path: Path, x: float, max_abs_diff: float | None
) -> None:
    path = tmp_path / "d.mcap"
    with RecordEvidence(_Labelled(), path) as rec:
        rec.reset(seed=0)
        rec.step(0)
    [episode] = replay([path], env_factory=lambda: _Labelled("b", x)).episodes
    assert episode.status == "not_replayable" and episode.divergence is not None  # (no spec)
    assert episode.divergence.field == "reset_observation"
    assert episode.divergence.max_abs_diff == max_abs_diff


def _heavier_cartpole() -> gym.Env[Any, Any]:
    """CartPole-v1 as recorded (its spec unchanged), its gravity changed after it was made."""
    env = gym.make("CartPole-v1")
    env.unwrapped.gravity = 20.0  # type: ignore[attr-defined]
    return env


def test_a_divergence_of_digested_observations_shows_the_digests_in_hex(tmp_path: Path) -> None:
    path = tmp_path / "digests.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path, digest_min_bytes=16) as env:
        env.reset(seed=0)
        for _ in range(3):
            env.step(0)
    (episode,) = replay([path], env_factory=_heavier_cartpole).episodes
    assert episode.status == "diverged" and episode.divergence is not None
    text = episode.divergence.describe()
    assert re.fullmatch(
        r"step 0: observation expected digest [0-9a-f]{32}, got digest [0-9a-f]{32}", text
    ), text
