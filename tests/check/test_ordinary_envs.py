"""``check`` is quiet on ordinary Gymnasium envs: what they do not report is a note.

CartPole reports no success, no failure label and no reward terms; Reacher never terminates;
a training loop stops mid-episode and closes its recorder; a vector loop stops right after an
episode ends and leaves a sub-env autoreset and never stepped. None of that is a warning, so
``check --strict`` passes their clean recordings with no ``--ignore``; a file a crash tore
still warns.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from typer.testing import CliRunner

from episode_audit import RecordEvidence, RecordVectorEvidence, open_evidence
from episode_audit.check import Finding, check
from episode_audit.cli import app

FIXTURES = Path(__file__).resolve().parents[2] / "fixtures"
LIMIT = {"CartPole-v1": 30, "Reacher-v5": 20}
"""A time limit short enough that some episodes of each env end by it."""


def _action(env_id: str, space: gym.Space[Any], episode: int, t: int) -> Any:
    """Scripted CartPole (alternate pushes: balances past the time limit; or push one way:
    falls in ~10 steps), by episode; random otherwise (``space`` is seeded)."""
    if env_id == "CartPole-v1":
        return t % 2 if episode % 2 == 0 else 0
    return space.sample()


def _record_single(env_id: str, path: Path, steps: int) -> Path:
    """Record ``steps`` steps with RecordEvidence, resetting as episodes end; close() cuts."""
    with RecordEvidence(gym.make(env_id, max_episode_steps=LIMIT[env_id]), path) as env:
        env.action_space.seed(0)
        env.reset(seed=0)
        episode = t = 0
        for _ in range(steps):
            _, _, terminated, truncated, _ = env.step(_action(env_id, env.action_space, episode, t))
            t += 1
            if terminated or truncated:
                episode, t = episode + 1, 0
                env.reset()
    return path


def _record_vector(env_id: str, path: Path, steps: int, mode: AutoresetMode) -> Path:
    """Record ``steps`` steps of a 2-env SyncVectorEnv with RecordVectorEvidence."""
    envs = gym.make_vec(
        env_id,
        2,
        vectorization_mode="sync",
        vector_kwargs={"autoreset_mode": mode},
        max_episode_steps=LIMIT[env_id],
    )
    with RecordVectorEvidence(envs, path) as recorder:
        recorder.action_space.seed(0)
        recorder.reset(seed=0)
        for _ in range(steps):
            recorder.step(recorder.action_space.sample())
    return path


def _strict(path: Path) -> tuple[int, str]:
    result = CliRunner().invoke(app, ["check", str(path), "--strict"])
    return result.exit_code, result.stdout


def _not_notes(findings: list[Finding]) -> list[Finding]:
    return [f for f in findings if f.severity != "note"]


@pytest.mark.parametrize("env_id", ["CartPole-v1", "Reacher-v5"])
@pytest.mark.parametrize("recorder", ["single", "next_step", "same_step"])
def test_check_strict_passes_clean_recordings_of_ordinary_envs(
    tmp_path: Path, env_id: str, recorder: str
) -> None:
    path = tmp_path / "run.mcap"
    if recorder == "single":
        _record_single(env_id, path, steps=107)
    else:
        mode = AutoresetMode.NEXT_STEP if recorder == "next_step" else AutoresetMode.SAME_STEP
        _record_vector(env_id, path, steps=75, mode=mode)
    episodes = open_evidence(path).episodes().to_pylist()
    # several episodes, a time-limit truncation among them, and the run cut by close()
    assert len(episodes) >= 4
    assert any(e["truncation_reason"] == "time_limit" for e in episodes)
    assert any(e["outcome"] == "incomplete" and e["length"] > 0 for e in episodes)
    result = check([path])
    assert _not_notes(result.findings) == []
    assert "incomplete_episode" in {f.code for f in result.findings}
    code, out = _strict(path)
    assert code == 0, out
    assert "0 error(s), 0 warning(s)" in out


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_a_vector_loop_that_stops_right_after_an_episode_ends(
    tmp_path: Path, mode: AutoresetMode
) -> None:
    """Sub-env 0 falls first and is autoreset; the loop stops when sub-env 1's episode ends.

    Sub-env 0's new episode runs on until close() cuts it (a note). Under ``SAME_STEP``
    sub-env 1's autoreset begins a 0-step episode at once; under ``NEXT_STEP`` one more step
    does (the loop takes it, as ``evaluate_policy``-style loops do): neither is reported.
    """
    path = tmp_path / "vec.mcap"
    envs = gym.make_vec(
        "CartPole-v1", 2, vectorization_mode="sync", vector_kwargs={"autoreset_mode": mode}
    )
    with RecordVectorEvidence(envs, path) as recorder:
        recorder.reset(seed=0)
        pushes = np.array([0, 1])  # push one way: falls; the other way, starting elsewhere
        while True:
            _, _, terminated, truncated, _ = recorder.step(pushes)
            if terminated[1] or truncated[1]:
                break
        if mode is AutoresetMode.NEXT_STEP:
            recorder.step(pushes)  # sub-env 1's reset step
    episodes = open_evidence(path).episodes().to_pylist()
    unstarted = [e["episode"] for e in episodes if e["length"] == 0]
    assert len(unstarted) == 1
    assert [e["env_index"] for e in episodes if e["episode"] in unstarted] == [1]
    running = [e["episode"] for e in episodes if e["outcome"] == "incomplete" and e["length"]]
    assert len(running) == 1
    result = check([path])
    assert result.episodes == len(episodes) - 1  # (the unstarted one is not counted, as in report)
    findings = result.findings
    assert _not_notes(findings) == []
    (cut,) = [f for f in findings if f.code == "incomplete_episode"]
    assert cut.severity == "note" and cut.episode == running[0]
    assert cut.message.endswith(f"(episodes {running[0]})")


def test_a_file_a_crash_tore_still_warns() -> None:
    """fixtures/torn.mcap: its recorder was killed (SIGKILL) mid-episode, never closed."""
    findings = check([FIXTURES / "torn.mcap"]).findings
    (cut,) = [f for f in findings if f.code == "incomplete_episode"]
    assert cut.severity == "warning"
    assert "cut off by the torn end of the file" in cut.message
    assert _strict(FIXTURES / "torn.mcap")[0] == 1


def test_an_unstarted_episode_is_not_called_unreplayable(tmp_path: Path) -> None:
    """Under ``SAME_STEP`` in an ``AsyncVectorEnv`` an autoreset episode has neither a seed
    nor an RNG state: not replayable. Sub-env 1's, reset as the loop stopped and never
    stepped, has nothing to replay: it was listed too (2 episodes, ``episodes 2, 3``)."""
    path = tmp_path / "async.mcap"
    envs = gym.make_vec(
        "CartPole-v1",
        2,
        vectorization_mode="async",
        vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP},
    )
    with RecordVectorEvidence(envs, path) as recorder:
        recorder.reset(seed=2)
        pushes = np.array([0, 1])  # sub-env 0 falls at step 9, sub-env 1 at step 10
        while True:
            _, _, terminated, truncated, _ = recorder.step(pushes)
            if terminated[1] or truncated[1]:
                break
    episodes = open_evidence(path).episodes().to_pylist()
    assert [(e["episode"], e["length"] == 0) for e in episodes if e["seed"] is None] == [
        (2, False),
        (3, True),
    ]
    (found,) = [f for f in check([path]).findings if f.code == "not_replayable"]
    assert (found.message, found.episode) == (
        "1 episode(s) have neither a reset seed nor an RNG state and cannot be replayed "
        "(episodes 2)",
        2,
    )


# (AsyncVectorEnv forks; Python 3.12+ warns when a thread is running then, e.g. ALE's)
@pytest.mark.filterwarnings("ignore:This process .* is multi-threaded:DeprecationWarning")
def test_an_unstarted_episode_of_unsaved_sub_env_state_is_not_listed(tmp_path: Path) -> None:
    """ALE's emulator state in workers no ResetRngInfo snapshots: the episodes an unseeded
    reset began cannot be replayed; the unseeded reset the loop ended with began episodes it
    never stepped, which were listed too (``4 episode(s) ... (episodes 2, 3, 4, 5)``)."""
    from gymnasium.vector import AsyncVectorEnv

    from tests.support.unsaved import short_pong

    path = tmp_path / "pong.mcap"
    envs = AsyncVectorEnv([short_pong] * 2)
    with pytest.warns(UserWarning, match="cannot be replayed"):
        recorder = RecordVectorEvidence(envs, path)
    with recorder:
        recorder.reset(seed=3)
        recorder.step(np.array([0, 1]))
        recorder.reset()
        recorder.step(np.array([0, 1]))
        recorder.reset()  # (then close: episodes 4 and 5 are never stepped)
    (found,) = [f for f in check([path]).findings if f.code == "not_replayable"]
    assert found.message.startswith(
        "2 episode(s) began with an unseeded reset and cannot be replayed (episodes 2, 3): the "
        "sub-envs' AtariEnv keeps state a seed does not set (ale_py.AtariEnv)"
    ), found.message


def test_an_unstarted_episode_s_replay_notes_are_not_findings(tmp_path: Path) -> None:
    """The same ``SAME_STEP`` file: the reset of episode 3 (never stepped) carries the note
    ``rng_state_unavailable``, which was a ``recorder_note`` warning for it (so ``--strict``
    failed over an episode that never ran); episode 2's, which ran, still is one."""
    path = tmp_path / "async.mcap"
    envs = gym.make_vec(
        "CartPole-v1",
        2,
        vectorization_mode="async",
        vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP},
    )
    with RecordVectorEvidence(envs, path) as recorder:
        recorder.reset(seed=2)
        while True:
            _, _, terminated, truncated, _ = recorder.step(np.array([0, 1]))
            if terminated[1] or truncated[1]:
                break
    noted = [
        (f.episode, f.step)
        for f in check([path]).findings
        if f.code == "recorder_note:rng_state_unavailable"
    ]
    assert noted == [(2, None)]


def test_the_unstarted_episodes_are_found_once_per_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The resets' notes and the episode records both leave them out, from one mask."""
    import importlib
    import pkgutil

    import episode_audit.format.records as records

    path = tmp_path / "cartpole.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        env.reset(seed=0)
        env.step(0)
        env.reset(seed=1)  # (then close: episode 1 is never stepped)
    found: list[int] = []

    def counted(table: Any) -> Any:
        found.append(table.num_rows)
        return records.unstarted(table)

    package = importlib.import_module("episode_audit.check")
    for module in pkgutil.iter_modules(package.__path__):
        named = importlib.import_module(f"episode_audit.check.{module.name}")
        if hasattr(named, "unstarted"):
            monkeypatch.setattr(named, "unstarted", counted)
    result = check([path])
    assert (result.ok, result.episodes) == (True, 1)
    assert found == [2]
