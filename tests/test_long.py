"""Long harnesses, run by `make test-long` (marked slow; not part of `make test`)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests import kill_harness


@pytest.mark.slow
def test_kill_harness_never_loses_flushed_steps(tmp_path: Path) -> None:
    """SIGKILL recordings at random steps, inside flushes and inside close(): see kill_harness."""
    kills = int(os.environ.get("EPISODE_AUDIT_KILLS", "120"))
    verdicts = kill_harness.run(
        kills, tmp_path, seed=int(os.environ.get("EPISODE_AUDIT_SEED", "2026"))
    )
    print(kill_harness.summary(verdicts))
    assert len(verdicts) == kills
    assert [(v.plan.index, v.problems) for v in verdicts if v.problems] == []


def _sb3_checked(path: Path) -> None:
    """Every episode of ``path`` replays identical; ``check --strict`` exits 0, no ``--ignore``."""
    from typer.testing import CliRunner

    from episode_audit import open_evidence, replay
    from episode_audit.cli import app

    result = replay([path])
    assert result.count("identical") + result.unstarted == open_evidence(path).episodes().num_rows
    strict = CliRunner().invoke(app, ["check", str(path), "--strict"])
    assert strict.exit_code == 0, strict.output


@pytest.mark.slow
@pytest.mark.parametrize("vec", ["dummy", "subproc"])
def test_sb3_ppo_cartpole_thousands_of_steps(tmp_path: Path, vec: str) -> None:
    """PPO on CartPole-v1, 8 192 steps over 4 sub-envs, recorded by RecordVecEnvEvidence."""
    pytest.importorskip("stable_baselines3")
    import gymnasium as gym
    import numpy as np
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor

    from episode_audit import ResetRngInfo, open_evidence
    from episode_audit.record.sb3 import RecordVecEnvEvidence

    torch.set_num_threads(1)
    make = [lambda: ResetRngInfo(gym.make("CartPole-v1"))] * 4
    base = DummyVecEnv(make) if vec == "dummy" else SubprocVecEnv(make, start_method="fork")
    path = tmp_path / "ppo.mcap"
    venv = VecMonitor(RecordVecEnvEvidence(base, path), str(tmp_path / "vm"))
    PPO("MlpPolicy", venv, n_steps=256, seed=0).learn(8192)
    venv.close()
    eps = open_evidence(path).episodes().to_pylist()
    assert sum(e["length"] for e in eps) == 8192
    csv = np.loadtxt(tmp_path / "vm.monitor.csv", delimiter=",", skiprows=2, ndmin=2)
    done = [e for e in eps if e["outcome"] != "incomplete"]
    assert sorted((int(r[1]), float(r[0])) for r in csv) == sorted(
        (e["length"], round(e["return"], 6)) for e in done
    )
    _sb3_checked(path)


@pytest.mark.slow
def test_sb3_sac_mujoco_thousand_steps(tmp_path: Path) -> None:
    """SAC on Reacher-v5 for 1 000 steps: rewards exact (float64), replay identical."""
    pytest.importorskip("stable_baselines3")
    pytest.importorskip("mujoco")
    import gymnasium as gym
    import torch
    from stable_baselines3 import SAC
    from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor

    from episode_audit import open_evidence
    from episode_audit.record.sb3 import RecordVecEnvEvidence

    torch.set_num_threads(1)
    path = tmp_path / "sac.mcap"
    inner = DummyVecEnv([lambda: gym.make("Reacher-v5")])
    venv = VecMonitor(RecordVecEnvEvidence(inner, path))
    SAC("MlpPolicy", venv, learning_starts=200, seed=0).learn(1000)
    venv.close()
    eps = open_evidence(path).episodes().to_pylist()
    # Reacher-v5: 50-step episodes (and the one its last autoreset began, never stepped)
    assert [e["length"] for e in eps if e["outcome"] != "incomplete"] == [50] * 20
    _sb3_checked(path)
