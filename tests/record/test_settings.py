"""The recorders' options (settings.py): declared once, checked once, alike for every recorder."""

from __future__ import annotations

import inspect
import re
import subprocess
import sys
import textwrap
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from episode_audit import (
    ConfigurationError,
    EndingRules,
    RecordAECEvidence,
    RecordEvidence,
    RecordParallelEvidence,
    RecordVectorEvidence,
    RewardTerms,
    open_evidence,
)
from episode_audit.record.settings import (
    DEFAULT_BLOCK_STEPS,
    RecorderOptions,
    RecorderSettings,
)


def _pettingzoo(name: str) -> Any:
    with warnings.catch_warnings():  # PettingZoo 1.27 deprecates env modules
        warnings.simplefilter("ignore", DeprecationWarning)
        from pettingzoo.classic import rps_v2, tictactoe_v3
    return rps_v2.parallel_env() if name == "parallel" else tictactoe_v3.env()


RECORDERS: dict[str, Callable[..., Any]] = {
    "RecordEvidence": lambda path, **kw: RecordEvidence(gym.make("CartPole-v1"), path, **kw),
    "RecordVectorEvidence": lambda path, **kw: RecordVectorEvidence(
        gym.make_vec("CartPole-v1", 2, vectorization_mode="sync"), path, **kw
    ),
    "RecordParallelEvidence": lambda path, **kw: RecordParallelEvidence(
        _pettingzoo("parallel"), path, **kw
    ),
    "RecordAECEvidence": lambda path, **kw: RecordAECEvidence(_pettingzoo("aec"), path, **kw),
}


@pytest.mark.parametrize("name", list(RECORDERS))
def test_every_recorder_refuses_an_unknown_option_as_python_would(
    name: str, tmp_path: Path
) -> None:
    path = tmp_path / "x.mcap"
    with pytest.raises(
        TypeError,
        match=rf"^{name}\.__init__\(\) got an unexpected keyword argument 'reward_term'$",
    ):
        RECORDERS[name](path, reward_term=["x"])
    assert not path.exists()


@pytest.mark.parametrize("name", list(RECORDERS))
def test_every_recorder_takes_every_option(name: str, tmp_path: Path) -> None:
    options: RecorderOptions = {
        "tags": {"policy": "random"},
        "reward_terms": ["reward_a"],
        "constant_terms": {"alive": 1.0},
        "ending_rules": EndingRules(success_keys=("won",)),
        "info_keys": "all",
        "digest_min_bytes": 1 << 20,
        "block_steps": 64,
        "flush_every_s": 5.0,
        "fsync": True,
        "overwrite": True,
        "command_line": ["train.py", "--seed", "1"],
        "transparent_wrappers": ["my_pkg.wrappers:MyLogger"],
    }
    assert set(options) == set(RecorderOptions.__annotations__)
    (tmp_path / "x.mcap").write_bytes(b"")  # overwrite=True replaces it
    recorder = RECORDERS[name](tmp_path / "x.mcap", **options)
    recorder.close()
    run = recorder.run_info
    assert run.tags == {"policy": "random"}
    assert run.command_line == ["train.py", "--seed", "1"]
    assert run.reward_terms == {"source": ["reward_a"], "constants": {"alive": 1.0}}
    assert run.ending_rules["success_keys"] == ["won"]
    assert run.recorder["info_keys"] == "all"
    assert run.recorder["flush_every_s"] == 5.0
    assert run.recorder["digest_min_bytes"] == 1 << 20
    assert run.recorder["transparent_wrappers"] == ["my_pkg.wrappers:MyLogger"]


def test_the_settings_defaults() -> None:
    settings = RecorderSettings()
    assert settings.block_steps == DEFAULT_BLOCK_STEPS
    assert settings.flush_every_s == 1.0
    assert settings.terms_rule == RewardTerms()
    assert settings.rules == EndingRules()
    assert (settings.info_keys, settings.keep_all_info, settings.track_info) == ((), False, False)
    assert settings.digest_min_bytes is None
    assert (settings.fsync, settings.overwrite) == (False, False)
    assert (settings.tags, settings.command_line) == (None, None)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"block_steps": 0}, "block_steps: expected an integer >= 1, actually: 0"),
        ({"flush_every_s": float("inf")}, "flush_every_s: expected a positive number"),
        ({"info_keys": "some"}, "info_keys: expected a list of keys or 'all', actually: 'some'"),
        ({"reward_terms": "reward_a"}, "reward terms source: expected 'auto'"),
        ({"constant_terms": {"alive": float("nan")}}, "constant reward term 'alive'"),
        ({"tags": ["a"]}, "^tags: expected a mapping of names to values, .* actually: list$"),
        (
            {"tags": {"notes": "x" * (1 << 20)}},
            r"^tags: expected at most 1048576 bytes of JSON \(what readers accept\), actually: "
            r"1048588 in 1 tags; keep tags short",
        ),
        (
            {"command_line": "python train.py"},
            "^command_line: expected a list of strings, as sys.argv, actually: str$",
        ),
        (
            {"command_line": ["train.py", 3]},
            r"^command_line\[1\]: expected a string, .* actually: int$",
        ),
        ({"command_line": ["x" * (1 << 20)]}, "^command_line: expected at most 1048576 bytes"),
        (
            {"flush_every_s": "1"},
            "^flush_every_s: expected a positive number of seconds, actually: '1'$",
        ),
        ({"block_steps": "64"}, "^block_steps: expected an integer >= 1, actually: '64'$"),
        ({"block_steps": 2.5}, "^block_steps: expected an integer >= 1, actually: 2.5$"),
        ({"info_keys": 3}, "^info_keys: expected a list of keys or 'all', actually: 3$"),
        (
            {"digest_min_bytes": "4096"},
            "^digest_min_bytes: expected an integer >= 1 or None, actually: '4096'$",
        ),
        (
            {"ending_rules": {"success_fn": None}},
            r"^ending_rules: expected an EndingRules, actually: dict; "
            r"pass EndingRules\(\*\*rules\)$",
        ),
        ({"ending_rules": "success"}, "^ending_rules: expected an EndingRules, actually: str"),
        (
            {"ending_rules": EndingRules(success_keys="done")},
            r"^ending_rules: success_keys: expected a sequence of info keys, got the string "
            r"'done'; pass success_keys=\('done',\)$",
        ),
        (
            {"reward_terms": 3},
            "^reward terms source: expected 'auto', a list of info keys, a callable or None, "
            "actually: 3$",
        ),
        (
            {"constant_terms": 1.0},
            "^constant reward terms: expected a mapping of names to numbers, e.g. "
            r"\{'alive_bonus': 1.0\}, actually: float$",
        ),
    ],
)
def test_the_settings_check_each_option(options: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigurationError, match=message):
        RecorderSettings(**options)


def test_tags_and_command_line_are_kept_as_text(tmp_path: Path) -> None:
    settings = RecorderSettings(tags={"seed": 3}, command_line=["train.py", tmp_path])  # type: ignore[dict-item, list-item]
    assert settings.tags == {"seed": "3"}
    assert settings.command_line == ["train.py", str(tmp_path)]


def test_an_env_spec_readers_would_refuse_is_left_out_with_a_note(tmp_path: Path) -> None:
    # a make() argument of 2 MiB: the run metadata would make the whole file unreadable
    path = tmp_path / "big.mcap"
    env = gym.make("CartPole-v1", disable_env_checker=True, render_mode=None)
    env.spec.kwargs["notes"] = "x" * (2 << 20)  # type: ignore[union-attr]
    with RecordEvidence(env, path) as recorder:
        recorder.reset(seed=0)
        recorder.step(0)
    evidence = open_evidence(path)
    assert evidence.run.env_spec is None and evidence.episodes().num_rows == 1
    (note,) = [n for n in evidence.run.recorder["notes"] if n.startswith("env spec")]
    assert re.fullmatch(r"env spec not recorded: \d+ bytes of JSON, over the 1048576 .*", note)


def test_a_space_readers_would_refuse_is_refused_before_the_file_is_made(tmp_path: Path) -> None:
    class Wide(gym.Env[Any, Any]):
        observation_space = gym.spaces.Box(
            low=-np.linspace(1, 2, 200_000, dtype=np.float32), high=np.float32(3)
        )
        action_space = gym.spaces.Discrete(2)

    path = tmp_path / "wide.mcap"
    with pytest.raises(
        ConfigurationError,
        match=r"^run metadata 'observation_space': \d+ bytes of JSON, over the 1048576 readers "
        r"accept, so no tool could read the file; record an env whose space is smaller",
    ):
        RecordEvidence(Wide(), path)
    assert not path.exists()


def test_constant_terms_join_a_reward_terms_rule() -> None:
    settings = RecorderSettings(
        reward_terms=RewardTerms(["a"], {"alive": 1.0}), constant_terms={"bonus": 2.0}
    )
    assert settings.terms_rule == RewardTerms(["a"], {"alive": 1.0, "bonus": 2.0})


def test_every_option_is_documented_once_in_the_settings() -> None:
    doc = inspect.cleandoc(RecorderSettings.__doc__ or "")  # (as Python >= 3.13 keeps it)
    for name in RecorderOptions.__annotations__:
        assert f"\n    {name}: " in doc, name
    for recorder in (RecordEvidence, RecordVectorEvidence):
        assert "RecorderSettings" in (recorder.__doc__ or "")


@pytest.mark.slow
def test_mypy_catches_a_misspelled_option(tmp_path: Path) -> None:
    snippet = tmp_path / "snippet.py"
    snippet.write_text(
        textwrap.dedent(
            """
            import gymnasium as gym

            from episode_audit import RecordEvidence, RecordVectorEvidence

            env = gym.make("CartPole-v1")
            RecordEvidence(env, "a.mcap", reward_terms=["x"], overwrite=True)
            RecordEvidence(env, "a.mcap", reward_term=["x"])
            RecordVectorEvidence(gym.make_vec("CartPole-v1", 2), "b.mcap", install_rng_inf=False)
            """
        )
    )
    found = subprocess.run(
        [sys.executable, "-m", "mypy", "--strict", "--follow-imports=silent", str(snippet)],
        capture_output=True,
        text=True,
        check=False,
    ).stdout
    assert 'Unexpected keyword argument "reward_term" for "RecordEvidence"' in found, found
    assert 'Unexpected keyword argument "install_rng_inf"' in found, found
    assert "Found 2 errors in 1 file" in found, found
