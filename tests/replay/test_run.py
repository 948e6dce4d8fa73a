"""replay()'s inputs: options checked, unreadable files kept going past, missing episodes."""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest

from episode_audit.errors import ConfigurationError, EpisodeAuditError, EvidenceError
from episode_audit.read.inputs import Unreadable
from episode_audit.replay import replay, replay_options
from episode_audit.rollout import record_episodes

FIXTURES = Path(__file__).resolve().parents[2] / "fixtures"
CLEAN = FIXTURES / "clean.mcap"
# (a CartPole file replays the same under any library versions; a MuJoCo one may not)
CARTPOLE = FIXTURES / "unlabeled_failure.mcap"


@pytest.mark.parametrize(
    ("atol", "episodes", "message"),
    [
        (float("nan"), None, "atol: expected a finite number >= 0, got nan"),
        (float("inf"), None, "atol: expected a finite number >= 0, got inf"),
        (-1.0, None, "atol: expected a finite number >= 0, got -1.0"),
        (0.0, [1, -2], "episodes: expected an episode index from 0 to 2**63 - 1, got -2"),
        (0.0, [2**63], f"episodes: expected an episode index from 0 to 2**63 - 1, got {2**63}"),
        (0.0, ["1"], "episodes: expected an episode index >= 0 (an int), got '1' (str)"),
        (0.0, "1", "episodes: expected a list of episode indices, got '1'; pass e.g. [0, 3]"),
        ("0", None, "atol: expected a finite number >= 0, got '0'"),
    ],
)
def test_replay_options_name_what_is_wrong(
    atol: float, episodes: list[int] | None, message: str
) -> None:
    with pytest.raises(ConfigurationError) as raised:
        replay_options(atol, episodes)
    assert str(raised.value) == message


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"episodes": "1"}, r"^episodes: expected a list of episode indices, got '1'"),
        ({"episodes": [True]}, r"^episodes: expected an episode index >= 0 \(an int\), got True"),
        ({"atol": float("nan")}, r"^atol: expected a finite number >= 0, got nan$"),
    ],
)
def test_replay_checks_its_options_as_the_command_line_does(
    options: dict[str, Any], message: str
) -> None:
    with pytest.raises(ConfigurationError, match=message):
        replay([CARTPOLE], **options)


def test_replay_options_name_the_options_as_the_caller_does() -> None:
    with pytest.raises(ConfigurationError, match=r"^--episode: expected an episode index"):
        replay_options(0.0, [-1], atol_option="--atol", episode_option="--episode")
    assert replay_options(0.5, iter([3, 1])) == [3, 1]
    assert replay_options(0.0) is None


def test_replay_raises_for_an_unreadable_file_unless_told_to_keep_going(tmp_path: Path) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x00" * 100)
    with pytest.raises(EvidenceError, match="not an MCAP file"):
        replay([CARTPOLE, bad])
    told: list[EpisodeAuditError] = []
    result = replay([bad, CARTPOLE], keep_going=True, on_error=told.append)
    assert [str(e) for e in told] == [f"{bad}: not an MCAP file (wrong magic bytes)"]
    assert result.unreadable == [Unreadable(str(bad), "not an MCAP file (wrong magic bytes)")]
    assert result.count("identical") == len(result.episodes) == 3
    assert not result.ok  # (a file could not be read: the command exits 2)
    assert "unreadable" not in result.to_dict()  # the JSON of replay() itself is as it was


def test_keep_going_does_not_hide_a_usage_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigurationError, match="no_such_module_for_test"):
        replay([CLEAN], imports=["no_such_module_for_test"], keep_going=True)
    with pytest.raises(ConfigurationError, match="it raised RuntimeError: boom from factory"):
        replay([CLEAN], env_factory="tests.support.factories:raises", keep_going=True)


def test_a_module_the_library_cannot_import_is_named_by_its_imports_argument() -> None:
    """The library's argument is ``imports=``; ``--import`` is the command's (test_cli.py)."""
    message = (
        r"^imports 'no_such_module_for_test': ModuleNotFoundError: No module named "
        r"'no_such_module_for_test'$"
    )
    with pytest.raises(ConfigurationError, match=message):
        replay([CLEAN], imports=["no_such_module_for_test"])
    with pytest.raises(ConfigurationError, match=message):
        record_episodes("CartPole-v1", "never.mcap", imports=["no_such_module_for_test"])


def test_missing_lists_the_selected_episodes_no_file_had() -> None:
    result = replay([CLEAN], episodes=[99, 1, 42])
    assert [e.episode for e in result.episodes] == [1] and result.missing == [42, 99]
    assert not result.ok  # (the command exits 2)
    assert replay([CLEAN]).missing == []


def test_imports_as_a_bare_string_is_refused_not_split_into_characters() -> None:
    with pytest.raises(
        ConfigurationError,
        match=r"^imports: expected a list of names, got the string 'os'; pass \['os'\]$",
    ):
        replay([CARTPOLE], imports="os")  # type: ignore[arg-type]


def test_an_env_factory_workers_cannot_be_sent_is_refused_before_any_work() -> None:
    """A lambda (or a local function) cannot be pickled for the worker processes."""
    factory = lambda: gym.make("CartPole-v1")  # noqa: E731
    hint = (
        r'; pass a function defined at the top level of a module, or "MODULE:CALLABLE", or jobs=1$'
    )
    with pytest.raises(
        ConfigurationError,
        match=r"^env_factory test_an_env_factory_workers_cannot_be_sent_is_refused_before_any_work"
        r"\.<locals>\.<lambda>: cannot be sent to the worker processes of jobs=2 "
        r"\(Can't (pickle|get) local object '.*<lambda>'\)" + hint,  # (3.13's pickle: "get")
    ):
        replay([CARTPOLE, CARTPOLE], env_factory=factory, jobs=2)
    # (one file is replayed in this process: the factory need not be sent)
    assert replay([CARTPOLE], env_factory=factory, jobs=2).ok
    # a module-level one is sent as it is
    assert replay([CARTPOLE, CARTPOLE], env_factory=partial(gym.make, "CartPole-v1"), jobs=2).ok
