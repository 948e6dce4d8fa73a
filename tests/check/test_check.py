from __future__ import annotations

import importlib
import json
import math
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest

from episode_audit import (
    ConfigurationError,
    CorruptEvidenceError,
    EndingRules,
    EpisodeAuditError,
    EvidenceError,
    RecordEvidence,
    open_evidence,
)
from episode_audit.check import CheckResult, Finding, check, check_evidence
from episode_audit.read import Evidence
from tests.support.envs import ScriptedEnv
from tests.support.typed_options import Logger

Step = tuple[Any, Any, Any, Any, Any]
OBS = np.zeros(2, np.float32)


def _record(
    path: Path,
    step: Callable[[ScriptedEnv, Any], Step],
    *,
    episodes: int = 1,
    max_steps: int = 50,
    reset: Callable[[ScriptedEnv], tuple[Any, Any]] | None = None,
    action: Any = 0,
    **kwargs: Any,
) -> Path:
    """Record ``episodes`` episodes of a ScriptedEnv, each until it ends or ``max_steps``."""
    with RecordEvidence(ScriptedEnv(step_fn=step, reset_fn=reset), path, **kwargs) as env:
        for seed in range(episodes):
            env.reset(seed=seed)
            for _ in range(max_steps):
                _, _, terminated, truncated, _ = env.step(action)
                if terminated or truncated:
                    break
    return path


def _codes(result: CheckResult | list[Finding]) -> list[str]:
    findings = result.findings if isinstance(result, CheckResult) else result
    return sorted(f.code for f in findings)


def _only(result: CheckResult | list[Finding], code: str) -> Finding:
    findings = result.findings if isinstance(result, CheckResult) else result
    found = [f for f in findings if f.code == code]
    assert len(found) == 1, findings
    return found[0]


def _terms_step(bad: dict[int, float], length: int = 6) -> Callable[[ScriptedEnv, Any], Step]:
    """Steps whose reward is the sum of their terms, plus ``bad[t]`` at step number t (1-based)."""

    def step(env: ScriptedEnv, action: Any) -> Step:
        terms = {"progress": 0.25 * env.t, "energy": -0.1}
        reward = sum(terms.values()) + bad.get(env.t, 0.0)
        return OBS, reward, env.t == length, False, {"reward_terms": terms, "success": True}

    return step


def test_clean_cartpole_file_is_ok(tmp_path: Path) -> None:
    path = tmp_path / "cartpole.mcap"
    with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=20), path) as env:
        env.action_space.seed(0)
        for seed in range(3):
            env.reset(seed=seed)
            done = False
            while not done:
                _, _, terminated, truncated, _ = env.step(env.action_space.sample())
                done = terminated or truncated
    result = check([path])
    assert result.ok and result.errors == 0
    assert result.files == [str(path)]
    assert result.episodes == 3
    assert result.steps == open_evidence(path).steps().num_rows
    assert "missing_terms" in _codes(result)
    assert not check([]).ok  # (nothing checked: no pass)
    assert not {"file_unfinished", "not_replayable", "missing_env_spec"} & set(_codes(result))
    missing = _only(result, "missing_terms")
    # CartPole reports no terms at all: a note, not a warning (the default "auto" source)
    assert missing.severity == "note" and missing.episode == 0 and missing.step == 0
    assert missing.message == (
        f"{result.steps} of {result.steps} steps have no reward terms (terms source 'auto'): "
        "the env reports none (no info['reward_terms'], no info['reward_*'] keys); name them "
        "with reward_terms= to check its rewards against them"
    )
    assert result.warnings == 0


def test_terms_that_do_not_sum_name_the_episode_and_first_step(tmp_path: Path) -> None:
    path = tmp_path / "terms.mcap"
    step_fn = _terms_step({3: 0.5, 5: -2.0})

    # the second episode is clean: only the first one gets a finding
    calls = {"episode": -1}

    def step(env: ScriptedEnv, action: Any) -> Step:
        if env.t == 1:
            calls["episode"] += 1
        if calls["episode"] == 1:
            return _terms_step({})(env, action)
        return step_fn(env, action)

    _record(path, step, episodes=2)
    result = check([path])
    assert not result.ok
    finding = _only(result, "terms_sum_mismatch")
    assert finding.severity == "error"
    assert (finding.episode, finding.step) == (0, 2)
    assert finding.file == str(path)
    assert finding.message.startswith("reward 1.15 != terms sum 0.65 (residual 0.5) at step 2;")
    assert "2 step(s) of the episode mismatch, worst residual 2" in finding.message
    assert "missing_terms" not in _codes(result)


def test_tolerances_are_honoured(tmp_path: Path) -> None:
    path = _record(tmp_path / "tol.mcap", _terms_step({2: 1e-4}))
    assert "terms_sum_mismatch" in _codes(check([path]))
    assert "terms_sum_mismatch" not in _codes(check([path], atol=1e-3))
    assert "terms_sum_mismatch" not in _codes(check([path], rtol=1e-3))


def test_declared_constant_terms_are_added_to_the_sum(tmp_path: Path) -> None:
    def step(env: ScriptedEnv, action: Any) -> Step:
        terms = {"progress": 0.5}
        return OBS, 0.5 + 1.0, env.t == 4, False, {"reward_terms": terms}

    declared = _record(tmp_path / "declared.mcap", step, constant_terms={"alive": 1.0})
    undeclared = _record(tmp_path / "undeclared.mcap", step)
    assert "terms_sum_mismatch" not in _codes(check([declared]))
    finding = _only(check([undeclared]), "terms_sum_mismatch")
    assert finding.message.startswith("reward 1.5 != terms sum 0.5 (residual 1) at step 0;")
    assert "4 step(s) of the episode mismatch" in finding.message
    # a constant the env does not add is just as wrong
    wrong = _record(tmp_path / "wrong.mcap", step, constant_terms={"alive": 1.0, "x": 2.0})
    finding = _only(check([wrong]), "terms_sum_mismatch")
    assert "!= terms sum 0.5 + constants 3 (residual 2)" in finding.message


def test_missing_terms_is_an_error_when_required(tmp_path: Path) -> None:
    def step(env: ScriptedEnv, action: Any) -> Step:
        info = {"reward_terms": {"a": 1.0}} if env.t % 2 else {}
        return OBS, 1.0, env.t == 4, False, info

    path = _record(tmp_path / "some.mcap", step)
    warning = _only(check([path]), "missing_terms")
    assert warning.severity == "warning"
    assert (warning.episode, warning.step) == (0, 1)
    assert warning.message.startswith("2 of 4 steps have no reward terms (terms source 'auto')")
    error = _only(check([path], require_terms=True), "missing_terms")
    assert error.severity == "error"
    assert not check([path], require_terms=True).ok


def test_missing_terms_is_a_note_when_recorded_without_terms(tmp_path: Path) -> None:
    """reward_terms=None says to keep none: a warning on every such file made --strict useless."""
    path = _record(
        tmp_path / "none.mcap",
        lambda env, action: (OBS, 1.0, env.t == 4, False, {}),
        reward_terms=None,
    )
    note = _only(check([path]), "missing_terms")
    assert note.severity == "note"
    assert note.message.startswith("4 of 4 steps have no reward terms (terms source None)")
    assert _only(check([path], require_terms=True), "missing_terms").severity == "error"


@pytest.mark.parametrize(
    ("source", "severity"),
    [("auto", "note"), (["reward_dist"], "warning"), (lambda info: None, "warning")],
)
def test_missing_terms_warns_only_where_terms_were_named(
    tmp_path: Path, source: Any, severity: str
) -> None:
    """No step has terms: the env reports none unless the recording said where they are."""
    path = _record(
        tmp_path / "none.mcap",
        lambda env, action: (OBS, 1.0, env.t == 4, False, {"x": 1.0}),
        reward_terms=source,
    )
    finding = _only(check([path]), "missing_terms")
    assert finding.severity == severity
    assert finding.message.startswith("4 of 4 steps have no reward terms")
    assert _only(check([path], require_terms=True), "missing_terms").severity == "error"


def test_nonfinite_reward_and_term(tmp_path: Path) -> None:
    def step(env: ScriptedEnv, action: Any) -> Step:
        terms = {"a": 1.0, "b": math.inf if env.t in (3, 4) else 0.0}
        reward = math.nan if env.t in (2, 5) else 1.0
        return OBS, reward, env.t == 6, False, {"reward_terms": terms}

    result = check([_record(tmp_path / "nan.mcap", step)])
    reward = _only(result, "nonfinite_reward")
    assert (reward.episode, reward.step, reward.severity) == (0, 1, "error")
    assert reward.message == "reward nan at step 1; 2 step(s) of the episode"
    term = _only(result, "nonfinite_term")
    assert (term.episode, term.step) == (0, 2)
    assert term.message == "term 'b' is inf at step 2; 2 step(s) of the episode"
    # rows with a non-finite reward or term are not also reported as a mismatch
    assert "terms_sum_mismatch" not in _codes(result)


def test_observation_and_action_outside_their_spaces(tmp_path: Path) -> None:
    def reset(env: ScriptedEnv) -> tuple[Any, Any]:
        return np.array([0.0, 5.0], np.float32), {}

    def step(env: ScriptedEnv, action: Any) -> Step:
        obs = np.full(2, 9.0, np.float32) if env.t in (2, 3) else OBS
        return obs, 0.0, env.t == 4, False, {}

    path = _record(tmp_path / "space.mcap", step, reset=reset, action=7)
    result = check([path])
    found = [f for f in result.findings if f.code == "observation_out_of_space"]
    assert [(f.episode, f.step) for f in found] == [(0, None), (0, 1)]
    assert found[0].message == (
        "observation outside its space at reset: array([0., 5.], dtype=float32); "
        "1 row(s) of the episode"
    )
    assert found[1].message.startswith("observation outside its space at step 1: array([9., 9.]")
    assert found[1].message.endswith("; 2 row(s) of the episode")
    action = _only(result, "action_out_of_space")
    assert (action.episode, action.step) == (0, 0)
    assert action.message == "action outside its space at step 0: 7; 4 row(s) of the episode"


def test_reset_observations_outside_their_space_in_many_reset_blocks(tmp_path: Path) -> None:
    # Checked one reset block at a time (image observations: one column of them all would
    # take their memory again): every episode's reset is checked, whichever block holds it.
    def reset(env: ScriptedEnv) -> tuple[Any, Any]:
        seed = env.np_random_seed
        return np.array([0.0, 5.0 if seed % 2 else 0.0], np.float32), {}

    def step(env: ScriptedEnv, action: Any) -> Step:
        return OBS, 0.0, env.t == 2, False, {}

    path = _record(tmp_path / "blocks.mcap", step, reset=reset, episodes=6, block_steps=4)
    blocks = open_evidence(path).resets().to_batches()
    assert len(blocks) >= 3
    found = [f for f in check([path]).findings if f.code == "observation_out_of_space"]
    assert [(f.episode, f.step) for f in found] == [(1, None), (3, None), (5, None)]


def test_unrebuildable_space_is_noted_and_skipped(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = _record(tmp_path / "plain.mcap", lambda e, a: (OBS, 0.0, e.t == 2, False, {}))
    monkeypatch.setattr(Evidence, "observation_codec", property(lambda self: None))
    result = check([path])
    note = _only(result, "observation_space_unchecked")
    assert note.severity == "note"
    assert note.message.startswith("the observation space cannot be rebuilt from the file")
    assert "action_space_unchecked" not in _codes(result)


def test_endings_unlabeled_failure_and_both_flags(tmp_path: Path) -> None:
    def step(env: ScriptedEnv, action: Any) -> Step:
        return OBS, 1.0, env.t == 2, env.t == 2, {}

    path = tmp_path / "both.mcap"
    with RecordEvidence(gym.wrappers.TimeLimit(ScriptedEnv(step_fn=step), 2), path) as env:
        for seed in range(3):
            env.reset(seed=seed)
            env.step(0)
            env.step(0)
    result = check([path])
    both = _only(result, "terminated_and_truncated")
    assert both.severity == "note" and both.episode == 0
    assert both.message == (
        "3 episode(s) ended with both terminated and truncated set; "
        "the task ending counts (episodes 0, 1, 2)"
    )
    unlabeled = _only(result, "unlabeled_failure")
    # the env labels no failure and the recording named no source of labels: a note
    assert unlabeled.severity == "note"
    assert unlabeled.message.startswith(
        "3 of 3 failure(s) have no label (episodes 0, 1, 2); the env labels no failure "
        "(no info['failure'] when it ends one)"
    )
    assert result.ok


def test_unlabeled_failures_of_an_env_without_success_say_endings_count_as_failures(
    tmp_path: Path,
) -> None:
    path = tmp_path / "cartpole.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        env.reset(seed=3)
        while not env.step(0)[2]:
            pass
    unlabeled = _only(check([path]), "unlabeled_failure")
    assert unlabeled.severity == "note"
    assert unlabeled.message == (
        "1 of 1 failure(s) have no label (episodes 0); the env labels no failure (no "
        "info['failure'] when it ends one) and reports no success, so every episode it ends "
        "counts as a failure; where an ending can be a success, record with "
        "ending_rules=EndingRules(success_fn=...)"
    )


@pytest.mark.parametrize(
    ("infos", "rules", "severity"),
    [
        ({}, None, "note"),  # no failure labelled, no source named
        ({0: {"failure": "fell"}}, None, "warning"),  # the env labels some failures
        ({0: {"cause": "fell"}}, EndingRules(failure_key="cause"), "warning"),  # named key
        ({}, EndingRules(failure_fn=lambda info: None), "warning"),  # a failure_fn
    ],
)
def test_unlabeled_failure_warns_where_labels_are_expected(
    tmp_path: Path, infos: dict[int, Any], rules: EndingRules | None, severity: str
) -> None:
    def step(env: ScriptedEnv, action: Any) -> Step:
        info = infos.get(env.episode, {}) if env.t == 2 else {}
        return OBS, 1.0, env.t == 2, False, info

    path = tmp_path / "labels.mcap"
    with RecordEvidence(ScriptedEnv(step_fn=step), path, ending_rules=rules) as env:
        for seed in range(3):
            env.reset(seed=seed)
            env.unwrapped.episode = seed  # type: ignore[attr-defined]
            env.step(0)
            env.step(0)
    unlabeled = _only(check([path]), "unlabeled_failure")
    assert unlabeled.severity == severity
    expected = 2 if 0 in infos else 3
    assert unlabeled.message.startswith(f"{expected} of 3 failure(s) have no label")


def test_labelled_failures_and_successes_are_not_flagged(tmp_path: Path) -> None:
    def step(env: ScriptedEnv, action: Any) -> Step:
        info = {"failure": "collision"} if env.t == 2 else {}
        return OBS, 1.0, env.t == 2, False, info

    result = check([_record(tmp_path / "labelled.mcap", step, episodes=2)])
    assert "unlabeled_failure" not in _codes(result)
    assert "terminated_and_truncated" not in _codes(result)


def test_error_episode(tmp_path: Path) -> None:
    def step(env: ScriptedEnv, action: Any) -> Step:
        if env.t == 3:
            raise RuntimeError("simulator exploded")
        return OBS, 1.0, False, False, {}

    path = tmp_path / "error.mcap"
    env = RecordEvidence(ScriptedEnv(step_fn=step), path)
    env.reset(seed=0)
    env.step(0)
    env.step(0)
    with pytest.raises(RuntimeError):
        env.step(0)
    env.close()
    finding = _only(check([path]), "error_episode")
    assert finding.severity == "error"
    assert (finding.episode, finding.step) == (0, 2)
    assert finding.message == (
        "the environment raised RuntimeError while taking step 2: simulator exploded"
    )


def test_incomplete_episode(tmp_path: Path) -> None:
    path = tmp_path / "incomplete.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        env.reset(seed=1)
        env.step(0)
        env.reset(seed=2)
        env.step(0)
    cut = [f for f in check([path]).findings if f.code == "incomplete_episode"]
    # episode 0 was cut by a reset: a warning; episode 1 by close(): a note
    assert [(f.severity, f.episode) for f in cut] == [("warning", 0), ("note", 1)]
    assert cut[0].message == "1 episode(s) stopped before they ended (episodes 0)"
    assert cut[1].message == (
        "1 episode(s) were running when the recorder was closed, at the end of the recording: "
        "their outcome is unknown and report counts them apart (episodes 1)"
    )


def test_torn_file(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path, block_steps=16) as env:
        env.action_space.seed(0)
        env.reset(seed=0)
        for _ in range(6):
            done = False
            while not done:
                _, _, terminated, truncated, _ = env.step(env.action_space.sample())
                done = terminated or truncated
            env.reset()
    data = path.read_bytes()
    cut = open_evidence(path)._chunks[-2].offset + 20
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(data[:cut])
    result = check([torn])
    unfinished = _only(result, "file_unfinished")
    assert unfinished.severity == "warning" and unfinished.episode is None
    assert unfinished.message.startswith("the writer did not finish the file (torn at byte")
    assert "length_mismatch" not in _codes(result)
    assert result.steps == open_evidence(torn).steps().num_rows > 0


def test_episode_spanning_several_blocks(tmp_path: Path) -> None:
    step_fn = _terms_step({4: 0.5, 20: 3.0}, length=30)

    def step(env: ScriptedEnv, action: Any) -> Step:
        obs, reward, terminated, truncated, info = step_fn(env, action)
        if env.t == 12:
            reward = math.nan
        return obs, reward, terminated, truncated, info

    path = _record(tmp_path / "long.mcap", step, episodes=2, block_steps=8)
    assert len(list(open_evidence(path).iter_step_batches())) > 4
    seen: list[int] = []
    result = check([path], progress=seen.append)
    assert sum(seen) == result.steps == 60 and len(seen) > 4
    mismatches = [f for f in result.findings if f.code == "terms_sum_mismatch"]
    assert [(f.episode, f.step) for f in mismatches] == [(0, 3), (1, 3)]
    assert "2 step(s) of the episode mismatch, worst residual 3" in mismatches[0].message
    assert [(f.episode, f.step) for f in result.findings if f.code == "nonfinite_reward"] == [
        (0, 11),
        (1, 11),
    ]
    assert "length_mismatch" not in _codes(result)
    assert "step_after_end" not in _codes(result)


def test_steps_after_the_end_across_blocks(tmp_path: Path) -> None:
    path = tmp_path / "after.mcap"
    with RecordEvidence(
        ScriptedEnv(step_fn=lambda e, a: (OBS, 1.0, e.t == 5, False, {})), path, block_steps=4
    ) as env:
        env.reset(seed=0)
        for _ in range(12):
            env.step(0)
    result = check([path])
    finding = _only(result, "step_after_end")
    assert (finding.episode, finding.step, finding.severity) == (0, 5, "error")
    assert finding.message == "7 step(s) recorded after the episode ended, first at step 5"
    # the recorder's own note is folded into this finding, and the record length still matches
    assert "recorder_note:step_after_end" not in _codes(result)
    assert "length_mismatch" not in _codes(result)


def test_steps_after_the_end_under_an_autoreset_name_it(tmp_path: Path) -> None:
    """An Autoreset deeper under the recorder resets the env unseen: the recorder warns, and
    check's finding names the wrapper rather than a missing reset() call."""
    path = tmp_path / "deep.mcap"
    env = gym.wrappers.ClipAction(
        gym.wrappers.Autoreset(gym.make("Pendulum-v1", max_episode_steps=5))
    )
    with pytest.warns(UserWarning, match="Autoreset under the recorder, not right under it"):
        recorder = RecordEvidence(env, path)
    with recorder as rec:
        rec.reset(seed=0)
        for _ in range(12):
            rec.step(np.zeros(1, np.float32))
    finding = _only(check([path]), "step_after_end")
    assert finding.message == (
        "7 step(s) recorded after the episode ended, first at step 5: the env's Autoreset "
        "wrapper reset it inside step(), not recorded as a reset; put Autoreset right under "
        "the recorder (which records those resets as episodes) or over it"
    )


def test_rows_after_the_outcome_row_without_recorder_notes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "after.mcap"
    with RecordEvidence(
        ScriptedEnv(step_fn=lambda e, a: (OBS, 1.0, e.t == 3, False, {})), path, block_steps=4
    ) as env:
        env.reset(seed=0)
        for _ in range(9):
            env.step(0)
    original = Evidence.iter_step_batches

    def without_notes(self: Evidence, columns: Sequence[str] | None = None) -> Any:
        for batch in original(self, columns):
            index = batch.schema.get_field_index("notes")
            yield batch.set_column(index, "notes", pa.nulls(batch.num_rows, pa.string()))

    monkeypatch.setattr(Evidence, "iter_step_batches", without_notes)
    finding = _only(check([path]), "step_after_end")
    assert (finding.episode, finding.step) == (0, 3)
    assert finding.message.startswith("6 step(s) recorded after the episode ended")


def test_length_mismatch(tmp_path: Path) -> None:
    path = _record(tmp_path / "len.mcap", lambda e, a: (OBS, 1.0, e.t == 3, False, {}), episodes=2)
    ev = open_evidence(path)
    table = ev.episodes()
    lengths = pc.add(table["length"], pa.array([0, 2])).combine_chunks()
    patched = table.set_column(table.schema.get_field_index("length"), "length", lengths)
    ev.episodes = lambda: patched  # type: ignore[method-assign]
    finding = _only(check_evidence(ev), "length_mismatch")
    assert (finding.episode, finding.severity) == (1, "error")
    # the one-file check leaves ignored codes out as check() does
    assert "length_mismatch" not in [f.code for f in check_evidence(ev, ignore=["length_mismatch"])]
    with pytest.raises(ConfigurationError, match="ignore: unknown finding code 'length'"):
        check_evidence(ev, ignore=["length"])
    assert finding.message == (
        "the episode record says 5 steps, the file holds 3 step rows up to its outcome"
    )


def test_recorder_notes_become_findings(tmp_path: Path) -> None:
    class Unserializable:
        pass

    def step(env: ScriptedEnv, action: Any) -> Step:
        if env.t == 1:
            return OBS, 1.0, False, False, {"thing": Unserializable()}
        if env.t == 2:
            return OBS, 1.0, False, False, {"reward_terms": {"a": "oops", "b": 1.0}}
        if env.t in (3, 4):
            return np.zeros(5, np.float32), 1.0, False, False, {}
        if env.t == 5:
            return OBS, "one", False, False, {}
        return OBS, 1.0, False, True, {}

    path = _record(tmp_path / "notes.mcap", step, info_keys="all")
    result = check([path])
    notes = {f.code: f for f in result.findings if f.code.startswith("recorder_note:")}
    assert set(notes) == {
        "recorder_note:info_unserializable",
        "recorder_note:term_not_numeric",
        "recorder_note:observation_invalid",
        "recorder_note:reward_not_numeric",
    }
    assert all(f.severity == "warning" and f.episode == 0 for f in notes.values())
    assert notes["recorder_note:term_not_numeric"].step == 1
    assert notes["recorder_note:term_not_numeric"].message == (
        "recorder noted term_not_numeric at step 1 (1 time(s) in the episode): term 'a' is 'oops'"
    )
    invalid = notes["recorder_note:observation_invalid"]
    assert invalid.step == 2
    assert invalid.message.startswith(
        "recorder noted observation_invalid at step 2 (2 time(s) in the episode): Expect shape"
    )
    assert notes["recorder_note:info_unserializable"].step == 0


def test_reset_options_held_in_their_typed_form_are_no_recorder_note(tmp_path: Path) -> None:
    """The ``options_unserializable`` note is for readers without ``options_typed``: a reset
    whose options that column holds is fine; one whose options no form holds is noted."""
    path = tmp_path / "options.mcap"
    with RecordEvidence(ScriptedEnv(), path) as env:
        for seed, options in enumerate([{"cap": math.inf, "at": (1, 2)}, {"log": Logger()}]):
            env.reset(seed=seed, options=options)
            env.step(0)
    notes = [f for f in check([path]).findings if f.code.startswith("recorder_note:")]
    assert [(f.code, f.episode) for f in notes] == [("recorder_note:options_unserializable", 1)]
    assert notes[0].message == (
        "recorder noted options_unserializable at reset (1 time(s) in the episode): "
        "{'log': <Logger>} (JSON has no Logger values; options_typed holds no Logger values)"
    )


def test_not_replayable_and_missing_env_spec(tmp_path: Path) -> None:
    path = tmp_path / "implicit.mcap"
    with RecordEvidence(ScriptedEnv(), path) as env:
        env.step(0)
        env.step(0)
    result = check([path])
    replay = _only(result, "not_replayable")
    assert replay.severity == "warning" and replay.episode == 0
    assert replay.message == (
        "1 episode(s) have neither a reset seed nor an RNG state and cannot be replayed "
        "(episodes 0)"
    )
    spec = _only(result, "missing_env_spec")
    assert spec.message == "no environment spec recorded: replay needs an env factory"
    # absent from the run metadata, as format.md says (not the JSON text "null")
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        run = next(m for m in make_reader(f).iter_metadata() if m.name == "episode_audit.run")
    assert "env_spec" not in run.metadata and "env_id" not in run.metadata
    assert "recorder_note:stepped_before_reset" in _codes(result)


def test_a_spec_with_a_placeholder_replay_needs_says_so(tmp_path: Path) -> None:
    path = tmp_path / "scaled.mcap"
    with RecordEvidence(gym.wrappers.TransformReward(gym.make("CartPole-v1"), abs), path) as env:
        env.reset(seed=0)
        env.step(0)
    spec = _only(check([path]), "missing_env_spec")
    assert spec.message == (
        "the environment spec holds placeholders for what JSON cannot hold (TransformReward's "
        "argument 'func'): replay needs an env factory"
    )
    assert open_evidence(path).run.recorder["notes"] == [
        "env spec recorded with placeholders for what JSON cannot hold: TransformReward's "
        "argument 'func' (replay needs an env factory to build what takes it)"
    ]


def test_older_format_version_is_noted(tmp_path: Path) -> None:
    path = _record(tmp_path / "old.mcap", lambda e, a: (OBS, 0.0, e.t == 1, False, {}))
    ev = open_evidence(path)
    ev.run.format_version = "0.9"
    note = _only(check_evidence(ev), "format_version")
    assert note.severity == "note"
    assert note.message == "written with format 0.9, older than the current 1.0"
    assert "format_version" not in _codes(check([path]))


def test_result_to_dict_is_stable_json(tmp_path: Path) -> None:
    path = _record(tmp_path / "terms.mcap", _terms_step({2: 1.0}))
    result = check([path, path])
    data = json.loads(json.dumps(result.to_dict(), allow_nan=False))
    assert list(data) == ["ok", "files", "episodes", "steps", "counts", "findings", "ignored"]
    assert data["ok"] is False
    assert data["files"] == [str(path), str(path)]
    assert (data["episodes"], data["steps"]) == (2, 12)
    # ScriptedEnv has no spec: one missing_env_spec warning per file
    assert data["counts"] == {"error": 2, "warning": 2, "note": 0}
    assert result.errors == 2 and result.warnings == 2 and result.notes == 0
    assert data["findings"][0]["code"] == "missing_env_spec"
    assert data["findings"][1] == {
        "severity": "error",
        "code": "terms_sum_mismatch",
        "message": data["findings"][1]["message"],
        "file": str(path),
        "episode": 0,
        "step": 1,
    }


def test_unreadable_file_raises_evidence_error(tmp_path: Path) -> None:
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"not evidence at all")
    with pytest.raises(EvidenceError, match="not an MCAP file"):
        check([garbage])


@pytest.mark.parametrize("option", ["atol", "rtol"])
@pytest.mark.parametrize("value", [-1.0, math.nan, math.inf, True])
def test_wrong_tolerances_are_configuration_errors(
    tmp_path: Path, option: str, value: float
) -> None:
    with pytest.raises(
        ConfigurationError, match=f"^{option}: expected a finite number >= 0, got {value!r}$"
    ):
        check([tmp_path / "unused.mcap"], **{option: value})


def test_grouping_keeps_recording_order_for_interleaved_rows() -> None:
    from episode_audit.check._state import first_per_episode as _first_per_episode

    episode = np.array([1, 0, 1, 0, 2, 1], dtype=np.int64)
    mask = np.array([True, True, True, False, True, True])
    values = np.array([0.5, 2.0, 3.0, 9.0, 1.0, 0.1])
    eps, first, counts, largest = _first_per_episode(episode, mask, values)
    assert eps.tolist() == [0, 1, 2]
    assert first.tolist() == [1, 0, 4]
    assert counts.tolist() == [1, 3, 1]
    assert largest is not None and largest.tolist() == [2.0, 3.0, 1.0]


def test_step_blocks_without_an_info_column_are_refused(tmp_path: Path) -> None:
    # Every column of docs/format.md's step block is required (later versions only add).
    from tests.support.hostile import rewrite

    source = tmp_path / "with_info.mcap"
    with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=3), source) as env:
        env.reset(seed=0)
        for _ in range(3):
            env.step(0)
    other = rewrite(source, tmp_path / "no_info.mcap", steps=lambda b: b.drop_columns(["info"]))
    with pytest.raises(CorruptEvidenceError, match=r"no_info\.mcap: .*'info' is missing"):
        check([other])


class _TextReward(gym.Wrapper[Any, Any, Any, Any]):
    def step(self, action: Any) -> Any:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, str(reward), terminated, truncated, info


def test_a_note_repeated_in_many_episodes_is_one_finding(tmp_path: Path) -> None:
    path = tmp_path / "text_reward.mcap"
    with RecordEvidence(_TextReward(gym.make("CartPole-v1", max_episode_steps=2)), path) as env:
        for seed in range(7):
            env.reset(seed=seed)
            env.step(0)
            env.step(0)
    noted = [f for f in check([path]).findings if f.code == "recorder_note:reward_not_numeric"]
    assert [(f.episode, f.step) for f in noted] == [(0, 0)]
    assert noted[0].message.startswith(
        "recorder noted reward_not_numeric on steps in 7 episodes "
        "(episodes 0, 1, 2, 3, 4 and 2 more; 14 time(s) in all): reward '1.0'"
    )


def test_a_recovered_copy_of_a_file_that_held_nothing_is_an_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A finished recovered copy with no episode (recover refuses to write one; an older
    episode-audit wrote them): a gate on check must not pass it."""
    from episode_audit import recover

    clean = (Path(__file__).parents[2] / "fixtures" / "clean.mcap").read_bytes()
    torn = tmp_path / "early.mcap"
    torn.write_bytes(clean[:1500])
    copy = tmp_path / "copy.mcap"
    # (the copy as an older recover wrote it: without its refusal of a file holding nothing)
    rewrite = importlib.import_module("episode_audit.recover.rewrite")
    monkeypatch.setattr(rewrite, "_refuse_empty", lambda src, copy: None)
    recover(torn, copy)
    result = check([copy])
    (finding,) = [f for f in result.findings if f.code == "file_recovered"]
    assert finding.severity == "error" and not result.ok
    assert finding.message.startswith(
        "rewritten by episode-audit recover from a torn or damaged file that held no complete "
        "chunk: no episode, reset or step survives to check; dropped: "
    )


def test_a_torn_file_that_holds_nothing_is_an_error(tmp_path: Path) -> None:
    """Torn after its run metadata, before its first chunk: its evidence is gone, and a gate on
    check must not pass it (a warning and exit 0 before); a live one's is a warning."""
    clean = (Path(__file__).parents[2] / "fixtures" / "clean.mcap").read_bytes()
    path = tmp_path / "early.mcap"
    path.write_bytes(clean[:1500])
    result = check([path])
    (finding,) = result.findings
    assert (finding.severity, finding.code) == ("error", "file_unfinished")
    assert not result.ok and result.episodes == 0
    assert re.search(
        r"the writer did not finish the file \(torn at byte \d+ of 1500: .*\) and no recorder "
        r"is writing it: it holds no complete chunk, so no episode, reset or step survives to "
        r"check \(a recorder killed before its first flush\) and `episode-audit recover` cannot "
        r"bring any back$",
        finding.message,
    ), finding.message
    # the same file while its recorder still runs: nothing flushed yet, nothing lost
    live = tmp_path / "live.mcap"
    env = RecordEvidence(gym.make("CartPole-v1"), live, flush_every_s=3600)
    try:
        env.reset(seed=0)
        env.step(0)
        (waiting,) = check([live]).findings
        assert (waiting.severity, waiting.code) == ("warning", "file_unfinished")
        assert "it holds no complete chunk yet" in waiting.message
    finally:
        env.close()
    # a torn file with chunks in it is read as before
    torn = check([Path(__file__).parents[2] / "fixtures" / "torn.mcap"])
    assert any(
        f.code == "file_unfinished" and f.message.endswith("complete chunks were read")
        for f in torn.findings
    )


# ------------------------------------------------------------------- ignored codes


def test_finding_codes_are_the_docs_table() -> None:
    """The codes ``ignore`` accepts are the ones docs/findings.md documents, in order."""
    from episode_audit.check import FINDING_CODES

    text = (Path(__file__).parents[2] / "docs" / "findings.md").read_text()
    documented = re.findall(r"^\| \[`([a-z_]+)(?::<code>)?`\]", text, re.M)
    assert documented == list(FINDING_CODES)


def test_ignored_codes_are_left_out_and_counted() -> None:
    fixture = Path(__file__).parents[2] / "fixtures" / "terms_mismatch.mcap"
    full = check([fixture])
    mismatches = [f for f in full.findings if f.code == "terms_sum_mismatch"]
    assert mismatches and not full.ok and full.ignored == 0
    result = check([fixture], ignore=["terms_sum_mismatch"])
    assert result.ok and result.ignored == len(mismatches)
    assert result.findings == [f for f in full.findings if f.code != "terms_sum_mismatch"]
    assert result.to_dict()["ignored"] == len(mismatches)
    assert result.errors == full.errors - len(mismatches)


def test_ignoring_recorder_note_ignores_every_recorder_note(tmp_path: Path) -> None:
    path = tmp_path / "text_reward.mcap"
    with RecordEvidence(_TextReward(gym.make("CartPole-v1", max_episode_steps=2)), path) as env:
        env.reset(seed=0)
        env.step(0)
    code = "recorder_note:reward_not_numeric"
    assert code in _codes(check([path]))
    for ignore in (["recorder_note"], [code]):
        result = check([path], ignore=ignore)
        assert code not in _codes(result) and result.ignored == 1, ignore
    assert code in _codes(check([path], ignore=["recorder_note:observation_cast"]))


@pytest.mark.parametrize("code", ["missing_term", "", "recorder_note:", "recorder_notes"])
def test_an_unknown_ignored_code_is_a_configuration_error(code: str) -> None:
    fixture = Path(__file__).parents[2] / "fixtures" / "clean.mcap"
    with pytest.raises(
        ConfigurationError,
        match=re.escape(
            f"ignore: unknown finding code {code!r}; known codes: terms_sum_mismatch, "
        ),
    ):
        check([fixture], ignore=[code])


def test_file_unfinished_says_the_writer_did_not_finish_once(tmp_path: Path) -> None:
    """Before: "the writer did not finish the file (ends at byte N without a summary: the writer
    did not finish); …" — the reader's reason repeated the message's opening words."""
    torn = Path(__file__).parents[2] / "fixtures" / "torn.mcap"
    size = torn.stat().st_size
    assert _only(check([torn]), "file_unfinished").message == (
        f"the writer did not finish the file (ends at byte {size} without a summary); "
        "complete chunks were read"
    )
    clean = (Path(__file__).parents[2] / "fixtures" / "clean.mcap").read_bytes()
    no_magic = tmp_path / "no_magic.mcap"
    no_magic.write_bytes(clean[:-8])  # the footer is there, the closing magic is not
    assert _only(check([no_magic]), "file_unfinished").message == (
        f"the writer did not finish the file (ends at byte {len(clean) - 8} without the closing "
        "magic); complete chunks were read"
    )


# ------------------------------------------------------------------- unreadable inputs


def test_keep_going_lists_unreadable_inputs_and_checks_the_others(tmp_path: Path) -> None:
    clean = Path(__file__).parents[2] / "fixtures" / "clean.mcap"
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x00" * 100)
    told: list[EpisodeAuditError] = []
    result = check([bad, clean], keep_going=True, on_error=told.append)
    alone = check([clean])
    assert result.files == [str(bad), str(clean)]
    assert (result.episodes, result.steps) == (alone.episodes, alone.steps)
    (error,) = told
    assert isinstance(error, EvidenceError)
    assert [(u.file, u.why) for u in result.unreadable] == [(str(bad), error.problem)]
    unreadable, *rest = result.findings
    assert (unreadable.severity, unreadable.code, unreadable.file) == (
        "error",
        "file_unreadable",
        str(bad),
    )
    assert unreadable.message == str(error) and not result.ok
    assert rest == alone.findings
    ignored = check([bad, clean], keep_going=True, ignore=["file_unreadable"])
    assert ignored.findings == alone.findings and ignored.ignored == 1
    assert len(ignored.unreadable) == 1
    # without keep_going, as before: the first unreadable input raises
    with pytest.raises(EvidenceError, match=r"bad\.mcap"):
        check([clean, bad])


def test_keep_going_still_raises_configuration_errors(tmp_path: Path) -> None:
    clean = Path(__file__).parents[2] / "fixtures" / "clean.mcap"
    with pytest.raises(ConfigurationError, match="atol: expected a finite number >= 0"):
        check([clean], atol=-1.0, keep_going=True)
