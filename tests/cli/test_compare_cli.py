"""`episode-audit compare`: outputs and exit codes (0 held/improved, 1 regressed or a gate
missed, 2 usage or unreadable input)."""

from __future__ import annotations

import json
from pathlib import Path

import cmarkgfm
import pytest
from typer.testing import CliRunner

from episode_audit.cli import app
from episode_audit.rollout import record_episodes
from episode_audit.tasks import DRAWER_OPEN_ID
from tests.support.rewards import record_cartpole

pytestmark = pytest.mark.mujoco
REPO = Path(__file__).resolve().parents[2]
runner = CliRunner()


def run(*args: str) -> tuple[int, str, str]:
    result = runner.invoke(app, list(args))
    if result.exception and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    out = tmp_path_factory.mktemp("cli")
    made = {}
    for name, policy, seed in [
        ("base", "scripted", 0),
        ("same", "scripted", 100),
        ("hack", "hacker", 0),
    ]:
        path = out / name / f"{name}.mcap"
        path.parent.mkdir()
        record_episodes(
            DRAWER_OPEN_ID, path, policy=policy, episodes=20, seed=seed,
            env_kwargs={"proxy_reward": True},
        )  # fmt: skip
        made[name] = str(path)
    return made


def test_regressed_exits_1_with_the_verdict_in_every_format(runs: dict[str, str]) -> None:
    code, out, _ = run("compare", runs["base"], "--candidate", runs["hack"], "-f", "json")
    assert code == 1
    data = json.loads(out)
    assert data["verdict"] == "regressed" and data["passed"] is False
    success = data["groups"][0]["metrics"][0]
    assert success["name"] == "success_rate" and success["paired"] and success["pairs"] == 20
    assert {c["status"] for c in data["cases"]} >= {"regressed", "new"}
    code, out, _ = run("compare", runs["base"], "--candidate", runs["hack"], "-f", "markdown")
    assert code == 1
    html = cmarkgfm.github_flavored_markdown_to_html(out)
    assert "<table>" in html and "<td>regressed</td>" in html
    assert "Incentive warnings new in the candidate" in html
    code, out, _ = run("compare", runs["base"], "--candidate", runs["hack"])
    assert code == 1 and "regressed" in out


def test_new_incentive_warnings_fail_only_their_gate(runs: dict[str, str]) -> None:
    args = ["compare", runs["base"], "--candidate", runs["hack"], "-f", "json"]
    data = json.loads(run(*args)[1])
    assert data["groups"][0]["new_warnings"] and data["groups"][0]["gates"] == []
    assert all(c["passed"] for c in data["cases"] if c["status"] == "new")
    code, out, _ = run(*args, "--fail-on-new-incentive-warning")
    (gate,) = json.loads(out)["groups"][0]["gates"]
    assert code == 1 and gate["gate"] == "new_incentive_warnings" and not gate["passed"]


def test_a_gate_on_a_label_no_failure_has_is_warned_as_report_does(
    runs: dict[str, str],
) -> None:
    args = ["compare", runs["base"], "--candidate", runs["same"]]
    code, _, err = run(*args, "--max-failure-increase", "drawer_yankd=0.5")
    assert code in (0, 1)
    assert "warning: gate max_failure_increase:drawer_yankd: no failure in these files is " in err
    assert "is the label spelt as recorded?" in err


def test_same_policy_other_seeds_exits_0(runs: dict[str, str]) -> None:
    base_dir = str(Path(runs["base"]).parent)  # a directory is searched for *.mcap
    code, out, err = run("compare", base_dir, "--candidate", runs["same"], "-f", "json")
    assert code == 0, err
    assert json.loads(out)["verdict"] in ("held", "inconclusive", "underpowered")


def test_a_missed_gate_exits_1(runs: dict[str, str]) -> None:
    args = ["compare", runs["base"], "--candidate", runs["same"], "-f", "json"]
    code, out, _ = run(*args, "--max-success-drop", "0.01")
    assert code == 1
    (gate,) = json.loads(out)["groups"][0]["gates"]
    assert gate["gate"] == "max_success_drop" and not gate["passed"]
    code, _, _ = run(*args, "--max-success-drop", "0.9", "--max-failure-increase", "0.9")
    assert code == 0


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--max-failure-increase", "drawer_yanked=2"], "--max-failure-increase: expected a rate"),
        (["--max-success-drop", "-1"], "--max-success-drop: expected a rate"),
        (["--max-return-drop", "nan"], "--max-return-drop: expected a finite number"),
        (["--rate-margin", "0"], "--rate-margin: expected a rate in"),
        (["--by", "file"], "by='file'"),
        (["--by", "label"], "by='label': each group would hold one outcome"),
        (["--by", "nope"], "by: expected"),
    ],
)
def test_usage_errors_exit_2(runs: dict[str, str], extra: list[str], message: str) -> None:
    code, _, err = run("compare", runs["base"], "--candidate", runs["same"], *extra)
    assert code == 2 and message in err, err


def test_a_baseline_path_after_candidate_or_a_file_on_both_sides_exit_2(
    runs: dict[str, str],
) -> None:
    # `--candidate runs/c-*.mcap`: the shell's glob puts every match but the first after it
    code, out, err = run("compare", runs["base"], "--candidate", runs["same"], runs["hack"])
    assert code == 2 and out == ""
    assert err.startswith(
        f"episode-audit: error: {runs['hack']} comes after --candidate, where it would be a "
        "BASELINE path: --candidate takes one path each time"
    ), err
    code, _, err = run("compare", "--candidate", runs["same"], "-f", "json", runs["base"])
    assert code == 2 and f"{runs['base']} comes after --candidate" in err
    base_dir = str(Path(runs["base"]).parent)
    code, _, err = run("compare", base_dir, runs["same"], "--candidate", runs["same"])
    assert code == 2
    assert f"error: {runs['same']} is on both sides: a file compared with itself" in err


def test_the_table_counts_each_sides_files(runs: dict[str, str]) -> None:
    _, out, _ = run(
        "compare", runs["base"], runs["hack"], "--candidate", runs["same"], "--by", "env"
    )
    assert "Candidate (1 file) against baseline (2 files), by env" in out
    _, out, _ = run("compare", runs["base"], "--candidate", runs["same"], "-f", "json")
    data = json.loads(out)
    assert (data["baseline_files"], data["candidate_files"]) == (1, 1)


def test_unreadable_input_or_different_task_exit_2(runs: dict[str, str], tmp_path: Path) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file")
    code, _, err = run("compare", runs["base"], str(bad), "--candidate", runs["same"])
    assert code == 2 and "bad.mcap" in err
    code, _, err = run("compare", runs["base"], "--candidate", str(tmp_path / "missing.mcap"))
    assert code == 2 and "no such file" in err
    cart = tmp_path / "cart.mcap"
    record_episodes("CartPole-v1", cart, episodes=3, max_episode_steps=10)
    code, _, err = run("compare", runs["base"], "--candidate", str(cart))
    assert code == 2 and "different tasks" in err and "pass --different-tasks" in err
    assert "different_tasks=True" not in err  # (the library's name for it, not the option's)
    code, _, err = run("compare", runs["base"], "--candidate", str(cart), "--different-tasks")
    assert code in (0, 1) and "env_id differs" in err


def test_an_unreadable_input_is_not_passed_in_json_junit_or_the_exit_code(
    runs: dict[str, str], tmp_path: Path
) -> None:
    # the comparison of the files read passed: JSON said "passed": true while the command
    # exited 2 (the schema: "passed" is exit 0; report already said false)
    import junitparser

    bad = tmp_path / "zero.mcap"
    bad.write_bytes(b"")
    args = ["compare", runs["base"], "--candidate", runs["same"], "--candidate", str(bad)]
    code, out, err = run(*args, "-f", "json")
    assert code == 2 and "zero.mcap: the file is empty" in err
    data = json.loads(out)
    assert data["passed"] is False
    assert [u["file"] for u in data["unreadable"]] == [str(bad)]
    assert run("compare", runs["base"], "--candidate", runs["same"], "-f", "json")[0] == 0
    code, out, _ = run(*args, "-f", "junit")
    xml = tmp_path / "compare.xml"
    xml.write_text(out)
    parsed = junitparser.JUnitXml.fromfile(str(xml))
    assert code == 2 and parsed.errors == 1  # (a CI reporter fails it too)


def test_a_comparison_that_cannot_be_made_still_prints_its_json_and_junit(
    runs: dict[str, str], tmp_path: Path
) -> None:
    import jsonschema
    import junitparser

    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file")
    code, out, err = run("compare", str(bad), "--candidate", runs["same"], "-f", "json")
    assert code == 2 and "none of its 1 evidence file(s) could be read" in err
    data = json.loads(out)
    schema = json.loads((REPO / "docs" / "schemas" / "compare.json").read_text())
    jsonschema.validate(data, schema, jsonschema.Draft202012Validator)
    assert data["error"].startswith("the baseline: none of its 1 evidence file(s)")
    assert [u["file"] for u in data["unreadable"]] == [str(bad)]
    code, out, _ = run("compare", str(bad), "--candidate", runs["same"], "-f", "junit")
    assert code == 2
    xml = tmp_path / "compare.xml"
    xml.write_text(out)
    cases = [(case.classname, case.name) for suite in junitparser.JUnitXml.fromfile(str(xml))
             for case in suite]  # fmt: skip
    assert cases == [(str(bad), "read"), ("episode-audit compare", "compare")]


def test_an_unfinished_file_is_compared_and_named(tmp_path: Path) -> None:
    import shutil

    torn = Path(__file__).resolve().parents[2] / "fixtures" / "torn.mcap"
    base, cand = (str(shutil.copy(torn, tmp_path / name)) for name in ("b.mcap", "c.mcap"))
    code, out, err = run("compare", base, "--candidate", cand, "-f", "json")
    assert code == 0, err
    assert "unfinished" in err
    data = json.loads(out)
    assert [u["file"] for u in data["unfinished"]] == [base, cand]
    assert data["groups"][0]["pairs"] > 0


def test_returns_of_other_reward_wrappers_are_not_compared(tmp_path: Path) -> None:
    scaled = str(record_cartpole(tmp_path / "scaled.mcap", "scaled"))
    plain = str(record_cartpole(tmp_path / "plain.mcap"))
    code, out, err = run("compare", scaled, "--candidate", plain, "--no-step-summary")
    assert code == 0  # (it was 1: the return `regressed` from x10 to the env's own)
    note = "Baseline 1/1 files' returns are not the env's: TransformReward"
    assert [line.rstrip() for line in out.splitlines()].count(note) == 1
    (row,) = [line for line in out.splitlines() if " return " in line]
    assert "- (other units)" in row and "not compared" in row and "inconclusive" in row
    assert (
        "episode-audit: warning: group all: return: not compared (inconclusive), nor a "
        "max_return_drop gate: the baseline's returns are TransformReward's and the "
        "candidate's the env's; record both sides over the same reward wrappers"
    ) in err
    gate = ("--max-return-drop", "1000", "--no-step-summary", "-f", "json")
    code, out, _ = run("compare", scaled, "--candidate", plain, *gate)
    assert code == 1  # a gate that cannot be verified fails
    (failed,) = [c for c in json.loads(out)["cases"] if not c["passed"]]
    assert failed["name"] == "all/gate:max_return_drop"
    assert failed["message"].startswith("return: cannot be verified, the baseline's returns")


def test_a_group_the_candidate_lacks_fails_its_gates_in_every_output(tmp_path: Path) -> None:
    import jsonschema
    import junitparser

    files = {}
    for name, config in [("b_short", "short"), ("b_long", "long"), ("c_short", "short")]:
        files[name] = str(tmp_path / f"{name}.mcap")
        record_episodes("CartPole-v1", files[name], episodes=6, max_episode_steps=10,
                        tags={"config": config})  # fmt: skip
    args = ["compare", files["b_short"], files["b_long"], "--candidate", files["c_short"]]
    args += ["--by", "tag:config", "--max-failure-increase", "1"]
    code, out, err = run(*args, "-f", "json")
    assert code == 1 and "group long: only the baseline" in err
    data = json.loads(out)
    schema = json.loads((REPO / "docs" / "schemas" / "compare.json").read_text())
    jsonschema.validate(data, schema, jsonschema.Draft202012Validator)
    assert data["passed"] is False and data["only_baseline"] == ["long"]
    (gate,) = data["only_baseline_gates"]
    assert (gate["gate"], gate["group"], gate["passed"]) == ("max_failure_increase", "long", False)
    assert {"name": "long/gate:max_failure_increase", "status": "failed", "passed": False,
            "message": gate["message"]} in data["cases"]  # fmt: skip
    code, out, _ = run(*args, "-f", "junit")
    xml = tmp_path / "compare.xml"
    xml.write_text(out)
    failed = [(suite.name, case.name) for suite in junitparser.JUnitXml.fromfile(str(xml))
              for case in suite if case.result]  # fmt: skip
    assert code == 1 and ("long", "gate:max_failure_increase") in failed
    code, out, _ = run(*args)
    assert code == 1 and "max_failure_increase  long   FAIL" in " ".join(out.split("\n"))


def test_n_needed_is_shown_only_for_metrics_not_yet_decided(runs: dict[str, str]) -> None:
    code, out, _ = run("compare", runs["base"], "--candidate", runs["hack"], "-f", "markdown")
    assert code == 1
    lines = out.splitlines()
    start = next(i for i, line in enumerate(lines) if "| n needed |" in line)
    table = lines[start : next(i for i in range(start, len(lines)) if not lines[i].strip())]
    rows = [line.split("|")[1:-1] for line in table]
    header = [cell.strip() for cell in rows[0]]
    verdict, needed = header.index("verdict"), header.index("n needed")
    decided = [r for r in rows[2:] if r[verdict].strip() in ("regressed", "improved", "held")]
    assert decided and all(r[needed].strip() == "-" for r in decided)
    data = json.loads(run("compare", runs["base"], "--candidate", runs["hack"], "-f", "json")[1])
    assert data["groups"][0]["metrics"][0]["n_needed"] is not None  # (the JSON keeps it)
