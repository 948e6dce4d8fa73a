"""CI outputs of check, replay and report: JUnit XML, the GitHub step summary, JSON Schemas.

JUnit documents are validated against Jenkins' junit-10.xsd (vendored beside this file, the
schema pytest checks its own junitxml against) and read back with junitparser, as a CI test
reporter reads them; JSON outputs against their published schemas in docs/schemas/.
"""

from __future__ import annotations

import copy
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import jsonschema
import junitparser
import pytest
import xmlschema
from typer.testing import CliRunner

from episode_audit import RecordEvidence
from episode_audit.cli import app
from episode_audit.cli._summary import STEP_SUMMARY_LIMIT, fit_summary
from episode_audit.cli.render import JUnitCase, junit_xml, safe
from episode_audit.rollout import record_episodes
from tests.support.crashing import crashing_cartpole
from tests.support.rewards import record_cartpole

REPO = Path(__file__).resolve().parents[2]
SCHEMAS = REPO / "docs" / "schemas"
runner = CliRunner()


@pytest.fixture(autouse=True)
def _in_repo(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(REPO)


@pytest.fixture(scope="module")
def junit_schema() -> xmlschema.XMLSchema:
    return xmlschema.XMLSchema(Path(__file__).with_name("junit-10.xsd"))


def run(*args: str, env: dict[str, str] | None = None) -> tuple[int, str, str]:
    result = runner.invoke(app, list(args), env=env)
    if result.exception and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


def cartpole(path: Path, episodes: int = 3) -> Path:
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        env.action_space.seed(0)
        for e in range(episodes):
            env.reset(seed=e)
            done = False
            while not done:
                _, _, term, trunc, _ = env.step(env.action_space.sample())
                done = term or trunc
    return path


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A CartPole file, a PettingZoo tic-tac-toe game, and a file that is not evidence."""
    import pettingzoo

    from episode_audit import RecordAECEvidence

    tmp = tmp_path_factory.mktemp("ci")
    junk = tmp / "junk.mcap"
    junk.write_bytes(b"not evidence")
    game = tmp / "ttt.mcap"
    with RecordAECEvidence(pettingzoo.make("aec", "classic/tictactoe-v3"), game) as env:
        env.reset(seed=0)
        for move in [0, 3, 1, 4, 2]:
            env.step(move)
        for _ in env.agent_iter():
            env.step(None)
    left = tmp / "left.mcap"  # the same seeds, always pushing left: a shorter return
    with RecordEvidence(gym.make("CartPole-v1"), left) as env:
        for e in range(20):
            env.reset(seed=e)
            while not any(env.step(0)[2:4]):
                pass
    files = {"cartpole": cartpole(tmp / "cp.mcap"), "game": game, "junk": junk, "left": left}
    files["random20"] = cartpole(tmp / "random20.mcap", episodes=20)
    # the same runs again, as a candidate (compare refuses a file on both sides)
    files["cartpole_again"] = Path(shutil.copy(files["cartpole"], tmp / "cp_again.mcap"))
    files["random20_again"] = Path(shutil.copy(files["random20"], tmp / "random20_again.mcap"))
    files["normalized"] = record_cartpole(tmp / "normalized.mcap", "normalized")  # (wrapped)
    files["clean"] = crashing_cartpole(tmp / "clean.mcap", 10)
    files["crashing"] = crashing_cartpole(tmp / "crashing.mcap", 10, lambda seed: seed % 2 == 0)
    for name in ("short", "short_again", "long"):  # (a group, long, the candidate lacks)
        files[name] = tmp / f"{name}.mcap"
        config = {"config": name.split("_")[0]}
        record_episodes("CartPole-v1", files[name], episodes=4, max_episode_steps=10, tags=config)
    return files


HEAVY = ("--env-factory", "tests.support.factories:heavy_cartpole")
BY_CONFIG, GATE = ("--by", "tag:config"), ("--max-failure-increase", "1")

# (command line, its exit code); {cartpole} and {junk} name the recorded files
SCENARIOS: list[tuple[tuple[str, ...], int]] = [
    (("check", "fixtures/clean.mcap"), 0),
    (("check", "fixtures/terms_mismatch.mcap"), 1),
    (("check", "fixtures/torn.mcap", "--strict"), 1),
    (("check", "fixtures/terms_mismatch.mcap", "--ignore", "terms_sum_mismatch"), 0),
    (("check", "fixtures/clean.mcap", "{junk}"), 2),
    (("replay", "{cartpole}"), 0),
    (("replay", "{cartpole}", *HEAVY), 1),
    (("replay", "fixtures/terms_mismatch.mcap"), 1),
    (("replay", "fixtures/terms_mismatch.mcap", "--allow-unverified"), 0),
    (("replay", "{cartpole}", "--episode", "9"), 2),
    (("replay", "{cartpole}", "{junk}"), 2),
    (("report", "fixtures/clean.mcap"), 0),
    (("report", "fixtures/clean.mcap", "--min-success-rate", "0.5"), 0),
    (("report", "fixtures", "--min-success-rate", "0.5", "--fail-on-incentive-warning"), 1),
    (("report", "fixtures", "--max-failure-rate", "collision=0.1", "--by", "all"), 0),
    (("report", "fixtures/torn.mcap", "{junk}", "--max-truncation-rate", "0.5"), 2),
    (("report", "{junk}"), 2),
    (("report", "{game}", "--games", "--by", "all", "--max-failure-rate", "0.5"), 1),
    (("report", "{game}", "--by", "agent"), 0),
    (("replay", "{game}"), 0),
    (("compare", "{cartpole}", "--candidate", "{cartpole_again}"), 0),
    (("compare", "{random20}", "--candidate", "{left}"), 1),
    (("compare", "{random20}", "--candidate", "{random20_again}", "--max-return-drop", "1"), 0),
    (("compare", "{cartpole}", "--candidate", "{cartpole_again}", "--candidate", "{junk}"), 2),
    (("compare", "{cartpole}", "--candidate", "{cartpole}"), 2),
    (("report", "{cartpole}", "{normalized}"), 0),
    (("compare", "{random20}", "--candidate", "{normalized}", "--max-return-drop", "100"), 1),
    (("compare", "{clean}", "--candidate", "{crashing}", "--max-error-increase", "0.5"), 1),
    (("compare", "{short}", "{long}", "--candidate", "{short_again}", *BY_CONFIG), 0),
    (("compare", "{short}", "{long}", "--candidate", "{short_again}", *BY_CONFIG, *GATE), 1),
    (("check", "fixtures/clean.mcap", "no-such.mcap"), 2),  # (no input found: an error document)
    (("replay", "no-such-folder"), 2),
    (("report", "fixtures/clean.mcap", "no-such.mcap"), 2),
    # refused while the arguments are parsed (Click's own checks, a BASELINE after --candidate)
    (("check", "fixtures/clean.mcap", "--jobs", "0"), 2),
    (("replay", "fixtures/clean.mcap", "--jobs", "0"), 2),
    (("compare", "{cartpole}", "--candidate", "{cartpole_again}", "{random20}"), 2),
]


def _args(args: tuple[str, ...], files: dict[str, Path]) -> list[str]:
    return [a.format(**{k: str(v) for k, v in files.items()}) for a in args]


def outcomes(xml: junitparser.JUnitXml) -> dict[tuple[str, str], tuple[str, str]]:
    """``(suite, case) -> (status, message)``, as a test reporter reads them."""
    found = {}
    for suite in xml:
        for case in suite:
            results = list(case.result)
            status = type(results[0]).__name__.lower() if results else "passed"
            found[(suite.name, case.name)] = (status, results[0].message if results else "")
    return found


def parse(text: str, schema: xmlschema.XMLSchema) -> junitparser.JUnitXml:
    schema.validate(text)
    return junitparser.JUnitXml.fromstring(text)


# ------------------------------------------------------------------------------ JUnit


@pytest.mark.parametrize(("args", "expected"), SCENARIOS)
def test_junit_is_valid_and_fails_exactly_when_the_command_does(
    args: tuple[str, ...],
    expected: int,
    recorded: dict[str, Path],
    junit_schema: xmlschema.XMLSchema,
) -> None:
    code, out, err = run(*_args(args, recorded), "--format", "junit")
    assert code == expected, err
    xml = parse(out, junit_schema)
    statuses = [status for status, _ in outcomes(xml).values()]
    assert ("failure" in statuses or "error" in statuses) == (code != 0), out
    assert ("error" in statuses) == (code == 2), out
    assert sum(suite.tests for suite in xml) == len(statuses)
    assert sum(suite.failures for suite in xml) == statuses.count("failure")


def test_check_junit_has_a_case_per_finding_kind(junit_schema: xmlschema.XMLSchema) -> None:
    from episode_audit.check import FINDING_CODES

    file = "fixtures/terms_mismatch.mcap"
    _, out, _ = run("check", file, "--format", "junit")
    found = outcomes(parse(out, junit_schema))
    assert [case for suite, case in found if suite == file] == list(FINDING_CODES)
    status, message = found[(file, "terms_sum_mismatch")]
    assert status == "failure"
    assert message.startswith("episode 1: reward 0.625 != terms sum 0.125"), message
    # a warning passes (its text is the case's output) unless --strict
    assert found[(file, "missing_env_spec")] == ("passed", "")
    xml = junitparser.JUnitXml.fromstring(out)
    (case,) = [c for s in xml for c in s if c.name == "missing_env_spec"]
    assert case.system_out.startswith("warning: no environment spec recorded")
    _, out, _ = run("check", file, "--strict", "--ignore", "terms_sum_mismatch", "-f", "junit")
    found = outcomes(parse(out, junit_schema))
    assert found[(file, "missing_env_spec")][0] == "failure"
    assert found[(file, "terms_sum_mismatch")] == ("skipped", "ignored (--ignore)")


def test_check_junit_an_unreadable_file_is_one_error(
    recorded: dict[str, Path], junit_schema: xmlschema.XMLSchema
) -> None:
    junk = str(recorded["junk"])
    code, out, _ = run("check", junk, "--format", "junit")
    assert code == 2
    found = outcomes(parse(out, junit_schema))
    assert list(found) == [(junk, "file_unreadable")]
    status, message = found[(junk, "file_unreadable")]
    assert status == "error" and "not" in message, message


def test_replay_junit_has_a_case_per_episode(
    recorded: dict[str, Path], junit_schema: xmlschema.XMLSchema
) -> None:
    file = str(recorded["cartpole"])
    _, out, _ = run("replay", file, "--format", "junit")
    found = outcomes(parse(out, junit_schema))
    assert found == {(file, f"episode {e}"): ("passed", "") for e in range(3)}
    code, out, _ = run("replay", file, *HEAVY, "--format", "junit")
    assert code == 1
    found = outcomes(parse(out, junit_schema))
    assert list(found) == [(file, f"episode {e}") for e in range(3)]
    for status, message in found.values():
        assert status == "failure" and message.startswith("step 0: observation expected")
    code, out, _ = run("replay", "fixtures/terms_mismatch.mcap", "--format", "junit")
    found = outcomes(parse(out, junit_schema))
    assert found.pop(("episode-audit replay", "verified"))[1].startswith(
        "replay verified no episode: all 3 episode(s) are not replayable"
    )
    assert {status for status, _ in found.values()} == {"skipped"}
    assert "pass --env-factory" in next(iter(found.values()))[1]
    code, out, _ = run("replay", file, "--episode", "7", "--format", "junit")
    assert code == 2
    found = outcomes(parse(out, junit_schema))
    assert found[("episode-audit replay", "episode 7")] == (
        "error",
        "no episode 7 in the file(s) given",
    )


def test_report_junit_has_a_case_per_gate_and_group(junit_schema: xmlschema.XMLSchema) -> None:
    args = ("report", "fixtures", "--min-success-rate", "0.5", "--max-failure-rate", "0.5")
    code, out, _ = run(*args, "--format", "junit")
    assert code == 1
    found = outcomes(parse(out, junit_schema))
    _, data, _ = run(*args, "--format", "json")
    gates = json.loads(data)["gates"]
    assert list(found) == [(g["group"], g["gate"]) for g in gates]
    for g in gates:
        assert found[(g["group"], g["gate"])] == (
            ("passed", "") if g["passed"] else ("failure", g["message"])
        )
    xml = junitparser.JUnitXml.fromstring(out)
    (case,) = [
        c for s in xml if s.name == "fixtures/torn.mcap" for c in s if c.name == "min_success_rate"
    ]
    body = case.result[0].text
    assert "group fixtures/torn.mcap: 12 episodes; success 0" in body
    assert "incentive warning" not in body  # (a torn CartPole file reports no success)
    # no gate: no test case (a valid, empty document)
    code, out, _ = run("report", "fixtures/clean.mcap", "--format", "junit")
    assert code == 0 and outcomes(parse(out, junit_schema)) == {}


def test_a_gate_case_lists_its_groups_incentive_warnings(
    tmp_path: Path, junit_schema: xmlschema.XMLSchema
) -> None:
    from tests.report.test_report import Plan, _record_plans

    plans = [Plan("success", reward=1.0)] * 2 + [Plan("failure:collision", reward=4.0)] * 3
    path = _record_plans(tmp_path / "hack.mcap", plans)
    code, out, _ = run(
        "report", str(path), "--by", "all", "--min-success-rate", "0.9", "-f", "junit"
    )
    assert code == 1
    parse(out, junit_schema)
    (case,) = [c for s in junitparser.JUnitXml.fromstring(out) for c in s]
    assert "incentive warning failure_outearns_success: failures labelled" in case.result[0].text


@pytest.mark.parametrize(
    "text",
    [
        "::error file=a.py,line=1::pwned",
        "##[error]x",
        "<b>&amp;</b> ]]> \"'",
        "\x00\x1b[31m\x07\ufffe\ud800 \u202e",
        "line one\r\nline two",
        "snow ☃ 雪 🙂",
    ],
)
def test_junit_xml_keeps_any_text_well_formed_and_literal(
    text: str, junit_schema: xmlschema.XMLSchema
) -> None:
    cases = [JUnitCase(text, text, status, text, text) for status in ("passed", "failed", "error")]
    cases.append(JUnitCase(text, "skipped", "skipped", text))
    out = junit_xml(cases, name=text)
    xml = parse(out, junit_schema)
    for line in out.splitlines():
        assert not line.lstrip().startswith("::") and "##[" not in line, line
    (suite,) = list(xml)
    assert suite.name == safe(text)
    messages = [case.result[0].message for case in suite if case.result]
    assert messages == [safe(text)] * 3


def test_compare_with_a_side_unreadable_says_so_in_one_line(recorded: dict[str, Path]) -> None:
    code, out, err = run("compare", str(recorded["cartpole"]), "--candidate", str(recorded["junk"]))
    assert code == 2 and not out
    assert err.splitlines()[-1] == (
        "episode-audit: error: the candidate: none of its 1 evidence file(s) could be read "
        "(the lines above say why); give readable files"
    )


def test_format_junit_only_where_offered() -> None:
    code, _, err = run("show", "fixtures/clean.mcap", "--format", "junit")
    assert code == 2 and "expected table, markdown or json, got 'junit'" in err
    code, _, err = run("check", "fixtures/clean.mcap", "--format", "xml")
    assert code == 2 and "expected table, markdown, json or junit, got 'xml'" in err


@pytest.mark.parametrize("command", ["check", "replay", "report", "compare"])
def test_help_lists_junit_and_the_step_summary_in_80_columns(command: str) -> None:
    code, out, _ = run(command, "--help", env={"COLUMNS": "80", "TERMINAL_WIDTH": "80"})
    assert code == 0
    assert max(len(line) for line in out.splitlines()) <= 80, out
    options = " ".join(out[out.index("--format") :].split())
    assert "json, or junit (CI test reporters)" in options, options
    assert "--no-step-summary" in options and "$GITHUB_STEP_SUMMARY" in options


# ------------------------------------------------------------------ GitHub step summary


@pytest.mark.parametrize(
    "args",
    [
        ("check", "fixtures/terms_mismatch.mcap"),
        ("replay", "{cartpole}"),
        ("report", "fixtures", "--min-success-rate", "0.5"),
    ],
)
def test_step_summary_is_the_markdown_output_appended(
    args: tuple[str, ...], recorded: dict[str, Path], tmp_path: Path
) -> None:
    argv = _args(args, recorded)
    code, markdown, _ = run(*argv, "--format", "markdown")
    summary = tmp_path / "summary.md"
    env = {"GITHUB_STEP_SUMMARY": str(summary)}
    assert not summary.exists()
    assert run(*argv, "--format", "json", env=env)[0] == code
    first = summary.read_text()
    assert first.strip() == markdown.strip()
    assert run(*argv, "--format", "junit", env=env)[0] == code  # a second command: appended
    assert summary.read_text() == first + "\n" + first
    before = summary.read_text()
    assert run(*argv, "--no-step-summary", env=env)[0] == code
    assert summary.read_text() == before
    # unset (outside GitHub Actions): nothing written
    assert run(*argv, "--format", "json", env={"GITHUB_STEP_SUMMARY": ""})[0] == code


def test_step_summary_once_when_stdout_is_already_appended_to_it(tmp_path: Path) -> None:
    """``episode-audit report ... --format markdown >> $GITHUB_STEP_SUMMARY`` writes it once."""
    summary = tmp_path / "summary.md"
    summary.write_text("")
    env = {**os.environ, "GITHUB_STEP_SUMMARY": str(summary), "PYTHONPATH": str(REPO)}
    command = [sys.executable, "-m", "episode_audit", "report", "fixtures/clean.mcap"]
    with summary.open("a") as out:
        subprocess.run([*command, "-f", "markdown"], stdout=out, env=env, check=True, cwd=REPO)
    once = summary.read_text()
    assert once.count("### episode-audit report") == 1, once
    subprocess.run([*command, "-f", "json"], capture_output=True, env=env, check=True, cwd=REPO)
    assert summary.read_text().count("### episode-audit report") == 2


def test_step_summary_is_cut_to_what_github_shows(tmp_path: Path) -> None:
    import cmarkgfm

    summary = tmp_path / "summary.md"
    summary.write_text("x" * (STEP_SUMMARY_LIMIT - 400) + "\n")
    code, _, _ = run("report", "fixtures", "-f", "json", env={"GITHUB_STEP_SUMMARY": str(summary)})
    assert code == 0
    data = summary.read_bytes()
    assert STEP_SUMMARY_LIMIT - 400 < len(data) <= STEP_SUMMARY_LIMIT
    added = data[STEP_SUMMARY_LIMIT - 399 :].decode()
    assert added.startswith("\n### episode-audit report"), added
    assert added.endswith("more line(s) did not fit in the step summary)_\n"), added
    html = cmarkgfm.github_flavored_markdown_to_html(added)
    assert "<em>(cut here:" in html, html
    # full: a warning, and the exit code stands
    summary.write_text("x" * STEP_SUMMARY_LIMIT)
    code, _, err = run("report", "fixtures", env={"GITHUB_STEP_SUMMARY": str(summary)})
    assert code == 0 and summary.stat().st_size == STEP_SUMMARY_LIMIT
    assert "warning: $GITHUB_STEP_SUMMARY" in err and "no summary appended" in err


@pytest.mark.parametrize("room", [0, 10, 90, 100, 101, 1000])
def test_fit_summary_stays_within_its_room_in_bytes(room: int) -> None:
    markdown = "### é\n" + "| ☃ | x |\n" * 20
    fitted = fit_summary(markdown, room)
    if fitted is None:
        assert room < 100
        return
    assert len(fitted.encode()) <= room
    assert fitted == markdown or fitted.startswith(markdown[: fitted.index("\n_(cut")])


def test_step_summary_that_cannot_be_written_is_a_warning(tmp_path: Path) -> None:
    code, _, err = run("check", "fixtures/clean.mcap", env={"GITHUB_STEP_SUMMARY": str(tmp_path)})
    assert code == 0
    assert "episode-audit: warning: $GITHUB_STEP_SUMMARY" in err and "cannot append" in err


# ----------------------------------------------------------------------- JSON Schemas


def _closed(schema: Any) -> Any:
    """``schema`` with every object that lists its properties closed to others: the outputs
    must declare each key they have, or this test fails (the published schema stays open)."""
    if isinstance(schema, dict):
        out = {k: _closed(v) for k, v in schema.items()}
        if "properties" in out and "additionalProperties" not in out:
            out["additionalProperties"] = False
        return out
    if isinstance(schema, list):
        return [_closed(v) for v in schema]
    return schema


@pytest.mark.parametrize("command", ["check", "replay", "report", "compare"])
def test_published_json_schemas_are_valid(command: str) -> None:
    schema = json.loads((SCHEMAS / f"{command}.json").read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["properties"]["command"] == {"const": command}
    assert f"docs/schemas/{command}.json" in (REPO / "docs" / "cli.md").read_text()


@pytest.mark.parametrize(("args", "expected"), SCENARIOS)
def test_json_output_follows_its_published_schema(
    args: tuple[str, ...], expected: int, recorded: dict[str, Path]
) -> None:
    from episode_audit.cli.render import JSON_SCHEMA_VERSION

    code, out, err = run(*_args(args, recorded), "--format", "json")
    assert code == expected, err
    data = json.loads(out)
    assert (data["command"], data["schema_version"]) == (args[0], JSON_SCHEMA_VERSION)
    schema = json.loads((SCHEMAS / f"{args[0]}.json").read_text())
    jsonschema.validate(data, _closed(copy.deepcopy(schema)), jsonschema.Draft202012Validator)


def test_a_json_schema_rejects_what_it_does_not_describe() -> None:
    """The strict check above can fail: an undeclared key, a missing one, a wrong type."""
    _, out, _ = run("check", "fixtures/terms_mismatch.mcap", "--format", "json")
    schema = _closed(json.loads((SCHEMAS / "check.json").read_text()))
    for broken in ({"extra": 1}, {"ok": "yes"}, {"schema_version": 2}):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate({**json.loads(out), **broken}, schema)
    data = json.loads(out)
    del data["findings"][0]["step"]
    with pytest.raises(jsonschema.ValidationError, match="'step' is a required property"):
        jsonschema.validate(data, schema)


def test_the_summary_names_the_unreadable_and_unfinished_files(tmp_path: Path) -> None:
    # compare's Markdown (and the step summary) named neither the inputs it could not read
    # (exit 2) nor the torn ones it compared; report's Markdown left the unreadable out
    base = record_cartpole(tmp_path / "base.mcap")
    cand = tmp_path / "cand"
    cand.mkdir()
    record_cartpole(cand / "good.mcap")
    (cand / "garbage.mcap").write_text("garbage\n")
    env = RecordEvidence(gym.make("CartPole-v1"), tmp_path / "whole.mcap", block_steps=16)
    for seed in range(4):
        env.reset(seed=seed)
        while not any(env.step(0)[2:4]):
            pass
    env.flush()
    (cand / "torn.mcap").write_bytes((tmp_path / "whole.mcap").read_bytes()[:-10])
    env.close()
    summary = tmp_path / "summary.md"
    args = ["compare", str(base), "--candidate", str(cand), "-j", "1", "--format", "junit"]
    assert run(*args, env={"GITHUB_STEP_SUMMARY": str(summary)})[0] == 2
    text = summary.read_text()
    assert "#### Unreadable files (not counted)" in text
    assert f"| {cand / 'garbage.mcap'} | not an MCAP file (wrong magic bytes) |" in text
    assert "#### Unfinished files (still being written, or torn): counts so far" in text
    assert f"| {cand / 'torn.mcap'} | torn at byte " in text
    code, out, _ = run("report", str(base), str(cand), "-j", "1", "--format", "markdown")
    assert code == 2 and "#### Unreadable files (not counted)" in out
    assert f"| {cand / 'garbage.mcap'} | not an MCAP file (wrong magic bytes) |" in out
    code, out, _ = run("compare", str(base), "--candidate", str(cand), "-j", "1")
    assert code == 2 and "Unreadable files (not counted)" in out and "Unfinished files" in out
