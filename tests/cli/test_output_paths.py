"""What the commands that write a file say of its path, in the command line's words."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from episode_audit import ConfigurationError
from episode_audit.cli import app
from episode_audit.export import export
from episode_audit.recover import recover

FIXTURES = Path(__file__).resolve().parents[2] / "fixtures"
CLEAN = FIXTURES / "clean.mcap"
TARGETS = [
    pytest.param("parquet", "out", id="parquet"),
    pytest.param("foxglove", "out.foxglove.mcap", id="foxglove"),
    pytest.param("rerun", "out.rrd", id="rerun"),
]


def _invoke(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, list(args))
    return result.exit_code, result.output


def _needs(to: str) -> None:
    if to != "parquet":
        pytest.importorskip("foxglove" if to == "foxglove" else "rerun")


@pytest.mark.parametrize(("to", "name"), TARGETS)
def test_an_existing_export_asks_for_the_command_line_s_own_flag(
    tmp_path: Path, to: str, name: str
) -> None:
    """The CLI said "pass overwrite=True (--overwrite)": the library's argument first."""
    _needs(to)
    out = tmp_path / name
    args = ["export", str(CLEAN), "--to", to, "-o", str(out)]
    assert _invoke(*args)[0] == 0
    code, said = _invoke(*args)
    assert code == 2
    assert re.fullmatch(
        r"episode-audit: error: \S+: exists; pass --overwrite to replace \S.*\n", said
    )
    with pytest.raises(ConfigurationError, match=r": exists; pass overwrite=True to replace") as e:
        export([CLEAN], out, to=to)  # type: ignore[call-overload]
    assert "--overwrite" not in str(e.value)
    assert _invoke(*args, "--overwrite")[0] == 0


def test_an_existing_recovery_output_asks_for_the_command_line_s_own_flag(tmp_path: Path) -> None:
    out = tmp_path / "fixed.mcap"
    out.write_bytes(b"keep")
    code, said = _invoke("recover", str(FIXTURES / "torn.mcap"), "-o", str(out))
    assert code == 2
    assert said == (
        f"episode-audit: error: {out}: file exists; recovery never overwrites it — choose "
        "another path or pass --overwrite\n"
    )
    with pytest.raises(ConfigurationError, match=r"or pass overwrite=True$"):
        recover(FIXTURES / "torn.mcap", out)
    assert out.read_bytes() == b"keep"


@pytest.mark.parametrize(("to", "name"), TARGETS)
def test_an_empty_output_path_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, to: str, name: str
) -> None:
    """``-o ""`` said ".: is a directory" (Path("") is the current folder); Parquet wrote there."""
    _needs(to)
    monkeypatch.chdir(tmp_path)
    assert _invoke("export", str(CLEAN), "--to", to, "-o", "") == (
        2,
        "episode-audit: error: --out: expected a path, got an empty string\n",
    )
    with pytest.raises(
        ConfigurationError, match=r"^out: expected a path, got an empty string; pass a file's path"
    ):
        export([CLEAN], "", to=to)  # type: ignore[call-overload]
    assert list(tmp_path.iterdir()) == []


def test_an_empty_recovery_output_path_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    assert _invoke("recover", str(FIXTURES / "torn.mcap"), "-o", "") == (
        2,
        "episode-audit: error: --out: expected a path, got an empty string\n",
    )
    with pytest.raises(
        ConfigurationError, match=r"^out: expected a path, got an empty string; pass a file's path"
    ):
        recover(FIXTURES / "torn.mcap", "")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", ["show", "recover"])
def test_a_directory_given_for_one_file_gets_command_line_advice(
    tmp_path: Path, command: str
) -> None:
    """``show runs`` pointed to the Python function ``episode_audit.read.evidence_files``."""
    (tmp_path / "b.mcap").write_bytes(CLEAN.read_bytes())
    (tmp_path / "a b.mcap").write_bytes(CLEAN.read_bytes())
    extra = ["-o", str(tmp_path / "out.mcap")] if command == "recover" else []
    code, said = _invoke(command, str(tmp_path), *extra)
    assert code == 2
    assert said == (
        f"episode-audit: error: {tmp_path}: a directory; {command} reads one evidence file: "
        f"name one of its .mcap files (e.g. '{tmp_path / 'a b.mcap'}')\n"
    )
    assert "episode_audit.read" not in said
    empty = tmp_path / "empty"
    empty.mkdir()
    code, said = _invoke(command, str(empty), *extra)
    assert said.endswith(f"{command} reads one evidence file: name one of its .mcap files\n")


def test_an_existing_recording_asks_for_the_command_line_s_own_flag(tmp_path: Path) -> None:
    """``record`` said "pass overwrite=True (--overwrite on the command line)"."""
    out = tmp_path / "run.mcap"
    out.write_bytes(b"keep")
    args = ["record", "CartPole-v1", "-o", str(out), "--episodes", "1"]
    code, said = _invoke(*args)
    assert code == 2
    assert said == (
        f"episode-audit: error: {out}: file exists; evidence is never overwritten — choose "
        "another path (the template 'run-{index}.mcap' takes the first free one), or pass "
        "--overwrite\n"
    )
    assert out.read_bytes() == b"keep"
    from episode_audit.rollout import record_episodes

    with pytest.raises(ConfigurationError, match=r"or pass overwrite=True \(--overwrite on the"):
        record_episodes("CartPole-v1", out, episodes=1)
    with pytest.raises(ConfigurationError, match=r"or pass --overwrite$"):
        record_episodes("CartPole-v1", out, episodes=1, overwrite_option="--overwrite")
    assert out.read_bytes() == b"keep"
    assert _invoke(*args, "--overwrite")[0] == 0
    assert out.stat().st_size > 4


def test_record_keeps_a_path_with_spaces_whole_in_its_result(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    out = "recorded runs/cart pole, the first of a longer series of runs.mcap"
    args = ["record", "CartPole-v1", "--episodes", "2", "--out", out]
    result = CliRunner().invoke(app, args, env={"COLUMNS": "80"})
    assert result.exit_code == 0, result.output
    assert out in result.output, result.output
