"""Every warning the recorders give is an ``EpisodeAuditWarning``, filterable by its category.

A ``RecorderWarning`` points at the line that made the recorder (this file), so only its
category picks it out; the recorder's trouble is also a ``RuntimeWarning``, and a recorder left
unclosed also a ``ResourceWarning``, so filters on those categories keep catching them.
"""

from __future__ import annotations

import gc
import re
import subprocess
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest
from gymnasium.vector import SyncVectorEnv
from gymnasium.wrappers import Autoreset, ClipReward
from gymnasium.wrappers.vector import TransformReward

import episode_audit
from episode_audit import RecordEvidence, RecordVectorEvidence
from episode_audit.errors import (
    EpisodeAuditWarning,
    RecorderTroubleWarning,
    RecorderWarning,
    UnclosedRecorderWarning,
    WorkerWarning,
)

_AUTORESET = "RecordEvidence: Autoreset under the recorder, not right under it: it resets"
_WRAPPED = "RecordVectorEvidence: the recorder wrapped the vector wrapper TransformReward"
_VEC_NORMALIZE = "RecordVecEnvEvidence: VecNormalize under the recorder"
_DELETED = r"run\.mcap was deleted while being recorded: "


def _cartpole() -> gym.Env[Any, Any]:
    return gym.make("CartPole-v1")


def _autoreset_deeper(path: Path) -> Any:
    return RecordEvidence(ClipReward(Autoreset(_cartpole()), -1, 1), path)


def _vector_wrapper_under(path: Path) -> Any:
    """(Its steps are recorded, not the sub-envs': warned as unrestorable.)"""
    return RecordVectorEvidence(TransformReward(SyncVectorEnv([_cartpole] * 2), abs), path)


def _vec_normalize(path: Path) -> Any:
    pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from episode_audit import RecordVecEnvEvidence

    return RecordVecEnvEvidence(VecNormalize(DummyVecEnv([_cartpole] * 2)), path)


MADE: list[tuple[Callable[[Path], Any], str]] = [
    (_autoreset_deeper, _AUTORESET),
    (_vector_wrapper_under, _WRAPPED),
    (_vec_normalize, _VEC_NORMALIZE),
]


def test_the_categories_are_exported_and_form_one_tree() -> None:
    for name in ("EpisodeAuditWarning", "RecorderWarning", "RecorderTroubleWarning"):
        assert name in episode_audit.__all__
    assert "UnclosedRecorderWarning" in episode_audit.__all__
    assert issubclass(EpisodeAuditWarning, UserWarning)
    for kind in (RecorderWarning, RecorderTroubleWarning, UnclosedRecorderWarning, WorkerWarning):
        assert issubclass(kind, EpisodeAuditWarning)
    assert issubclass(RecorderTroubleWarning, RuntimeWarning)
    assert issubclass(UnclosedRecorderWarning, ResourceWarning)


@pytest.mark.parametrize(("make", "message"), MADE, ids=lambda x: getattr(x, "__name__", ""))
def test_a_warning_at_construction_is_made_an_error_by_its_category(
    tmp_path: Path, make: Callable[[Path], Any], message: str
) -> None:
    path = tmp_path / "run.mcap"
    for category in (EpisodeAuditWarning, RecorderWarning):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            warnings.simplefilter("error", category)
            with pytest.raises(RecorderWarning, match=message):
                make(path)
        assert not path.exists()  # (warned before the file is made)


@pytest.mark.parametrize(("make", "message"), MADE, ids=lambda x: getattr(x, "__name__", ""))
def test_a_warning_at_construction_names_the_users_line_and_is_ignored_by_its_category(
    tmp_path: Path, make: Callable[[Path], Any], message: str
) -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        make(tmp_path / "a.mcap").close()
    ours = [w for w in caught if issubclass(w.category, EpisodeAuditWarning)]
    assert ours and all(w.category is RecorderWarning for w in ours)
    assert any(re.search(message, str(w.message)) for w in ours)
    assert all(w.filename == __file__ for w in ours)  # (where the recorder was made)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warnings.filterwarnings("ignore", category=RecorderWarning)
        make(tmp_path / "b.mcap").close()
    assert not [w for w in caught if issubclass(w.category, EpisodeAuditWarning)]


def _deleted_while_recorded(path: Path) -> RecordEvidence[Any, Any]:
    env = RecordEvidence(_cartpole(), path)
    env.reset(seed=0)
    path.unlink()
    return env


@pytest.mark.parametrize("category", [EpisodeAuditWarning, RecorderTroubleWarning, RuntimeWarning])
def test_the_recorders_trouble_is_made_an_error_by_its_category_or_runtime_warning(
    tmp_path: Path, category: type[Warning]
) -> None:
    env = _deleted_while_recorded(tmp_path / "run.mcap")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        warnings.simplefilter("error", category)
        with pytest.raises(RecorderTroubleWarning, match=_DELETED):
            env.flush()
    env.close()


def test_the_recorders_trouble_is_ignored_by_its_category(tmp_path: Path) -> None:
    env = _deleted_while_recorded(tmp_path / "run.mcap")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warnings.filterwarnings("ignore", category=RecorderTroubleWarning)
        env.flush()
        env.close()
    assert not [w for w in caught if issubclass(w.category, EpisodeAuditWarning)]


@pytest.mark.parametrize("category", [EpisodeAuditWarning, ResourceWarning])
def test_an_unclosed_recorder_is_warned_of_in_its_category(
    tmp_path: Path, category: type[Warning]
) -> None:
    path = tmp_path / "run.mcap"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("ignore")
        warnings.simplefilter("always", category)
        env = RecordEvidence(_cartpole(), path)
        env.reset(seed=0)
        del env
        gc.collect()
    unclosed = [w for w in caught if "RecordEvidence for" in str(w.message)]
    assert [w.category for w in unclosed] == [UnclosedRecorderWarning]
    assert f"RecordEvidence for {path} was not closed; call close()" in str(unclosed[0].message)


_NEVER_CLOSED = """
import gc
import sys
import gymnasium as gym
from episode_audit import RecordEvidence

def dropped(path):
    env = RecordEvidence(gym.make("CartPole-v1"), path)
    env.reset(seed=0)
    for _ in range(5):
        env.step(0)

dropped(sys.argv[1])
gc.collect()  # (the dropped recorder collected here, unclosed)
kept = RecordEvidence(gym.make("CartPole-v1"), sys.argv[2])
kept.reset(seed=1)
for _ in range(5):
    kept.step(1)
print("exiting", flush=True)  # (exits with the recorder open)
"""


def test_a_recorder_never_closed_gives_one_warning_and_a_finished_file(tmp_path: Path) -> None:
    """Collected unclosed: our warning only (no ResourceWarning for its file object), the file
    finished then; still open at exit: finished by the exit hook, silently."""
    from episode_audit import check

    dropped, kept = tmp_path / "dropped.mcap", tmp_path / "kept.mcap"
    done = subprocess.run(
        [sys.executable, "-W", "default", "-c", _NEVER_CLOSED, str(dropped), str(kept)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0 and done.stdout == "exiting\n", done.stderr
    warned = [line for line in done.stderr.splitlines() if "Warning" in line]
    assert len(warned) == 1, done.stderr
    assert re.search(
        rf"UnclosedRecorderWarning: episode-audit: RecordEvidence for {re.escape(str(dropped))} "
        r"was not closed; call close\(\)",
        warned[0],
    ), done.stderr
    for path, steps in ((dropped, 5), (kept, 5)):
        result = check([path])
        codes = {f.code for f in result.findings}
        assert "file_unfinished" not in codes and not result.warnings, (path, codes)
        assert episode_audit.open_evidence(path).steps(columns=["episode"]).num_rows == steps
