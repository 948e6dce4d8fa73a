"""The GitHub Actions workflow of docs/ci.md, run the way its runner runs it (without `act`).

Every ``run:`` step but ``install`` runs as GitHub runs it (``bash -e``, the workflow's
``env``, a ``$GITHUB_STEP_SUMMARY`` file per step), in a fresh directory, with
``episode-audit`` this checkout's CLI; a failed step stops the job, as it does there. Then
what the ``uses:`` steps would take (the artifact's paths, the JUnit files) must be there.
"""

from __future__ import annotations

import glob
import os
import stat
import subprocess
import sys
from pathlib import Path
from typing import Any

import junitparser
import pytest
import xmlschema
import yaml

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "ci.md"


def workflow() -> dict[str, Any]:
    """The workflow: the YAML block after the heading ``## The workflow``."""
    text = DOC.read_text().split("\n## The workflow\n", 1)[1]
    block = text.split("```yaml\n", 1)[1].split("\n```", 1)[0]
    data: dict[str, Any] = yaml.safe_load(block)
    return data


def steps() -> list[dict[str, Any]]:
    (job,) = workflow()["jobs"].values()
    return list(job["steps"])


def run_job(tmp: Path, **env_overrides: str) -> list[tuple[dict[str, Any], int]]:
    """Run the job's ``run:`` steps in ``tmp``; ``(step, exit code)`` of those that ran."""
    shim = tmp / "bin" / "episode-audit"
    shim.parent.mkdir()
    shim.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m episode_audit "$@"\n')
    shim.chmod(shim.stat().st_mode | stat.S_IXUSR)
    work = tmp / "work"
    work.mkdir()
    env = {
        **os.environ,
        **{k: str(v) for k, v in workflow()["env"].items()},
        **env_overrides,
        "PATH": f"{shim.parent}{os.pathsep}{os.environ['PATH']}",
        "PYTHONPATH": str(REPO),
        "CI": "true",
    }
    ran: list[tuple[dict[str, Any], int]] = []
    for i, step in enumerate(steps()):
        if "run" not in step or step.get("id") == "install":
            continue
        assert "${{" not in step["run"], step  # (an expression this test would not expand)
        summary = tmp / f"summary-{i}.md"
        step_env = {**env, "GITHUB_STEP_SUMMARY": str(summary)}
        done = subprocess.run(
            ["bash", "-e", "-c", step["run"]],
            cwd=work,
            env=step_env,
            capture_output=True,
            text=True,
            timeout=600,
            check=False,
        )
        step["summary"], step["stderr"] = summary, done.stderr
        ran.append((step, done.returncode))
        if done.returncode:
            break
    return ran


def junit_files(work: Path) -> list[Path]:
    (publish,) = [s for s in steps() if "junit" in s.get("uses", "")]
    return sorted(Path(p) for p in glob.glob(str(work / publish["with"]["report_paths"])))


@pytest.fixture(scope="module")
def junit_schema() -> xmlschema.XMLSchema:
    return xmlschema.XMLSchema(REPO / "tests" / "cli" / "junit-10.xsd")


def test_workflow_shape() -> None:
    names = [s.get("id") for s in steps()]
    assert "compare" in names and "install" in names
    (install,) = [s for s in steps() if s.get("id") == "install"]
    pyproject = (REPO / "pyproject.toml").read_text()
    assert "'episode-audit[mujoco]'" in install["run"] and "\nmujoco = [" in pyproject
    always = [s["name"] for s in steps() if s.get("if") == "success() || failure()"]
    assert always == ["Keep the evidence", "Publish the test results"]


def test_workflow_runs_as_documented(tmp_path: Path, junit_schema: xmlschema.XMLSchema) -> None:
    ran = run_job(tmp_path)
    assert [code for _, code in ran] == [0] * len(ran), [(s["name"], s["stderr"]) for s, _ in ran]
    assert len(ran) == len([s for s in steps() if "run" in s]) - 1
    work = tmp_path / "work"
    (keep,) = [s for s in steps() if "upload-artifact" in s.get("uses", "")]
    for path in keep["with"]["path"].split():
        assert list((work / path).glob("*.mcap")), path
    files = junit_files(work)
    assert [f.name for f in files] == ["check.xml", "compare.xml", "replay.xml", "report.xml"]
    for file in files:
        junit_schema.validate(str(file))
        xml = junitparser.JUnitXml.fromfile(str(file))
        cases = [case for suite in xml for case in suite]
        # compare skips the metrics it cannot decide either way (underpowered, inconclusive)
        assert cases and all(case.is_passed or case.is_skipped for case in cases), file
    audits = [s for s, _ in ran if "episode-audit record" not in s["run"]]
    assert len(audits) == 4
    for step in audits:  # every check / replay / report step wrote the job summary
        assert step["summary"].read_text().startswith("### episode-audit "), step["name"]
    (compare,) = [s for s, _ in ran if s.get("id") == "compare"]
    text = compare["summary"].read_text()
    assert text.startswith("### episode-audit compare: ") and "regressed" not in text, text


def test_workflow_fails_the_job_on_a_reward_hacking_candidate(
    tmp_path: Path, junit_schema: xmlschema.XMLSchema
) -> None:
    ran = run_job(tmp_path, CANDIDATE_POLICY="hacker")
    (last, code) = ran[-1]
    assert last.get("id") == "compare" and code == 1, last["stderr"]
    assert [c for _, c in ran[:-1]] == [0] * (len(ran) - 1)
    compared = tmp_path / "work" / "compare.xml"
    junit_schema.validate(str(compared))
    failed = [
        case.name
        for suite in junitparser.JUnitXml.fromfile(str(compared))
        for case in suite
        if not (case.is_passed or case.is_skipped)
    ]
    assert "success_rate" in failed, failed
    assert last["summary"].read_text().startswith("### episode-audit compare: regressed")
