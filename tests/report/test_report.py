from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from episode_audit import (
    ConfigurationError,
    EvidenceError,
    RecordEvidence,
    RecordVectorEvidence,
    open_evidence,
)
from episode_audit.report import (
    Gates,
    GroupReport,
    Interval,
    Report,
    report,
    report_tables,
    wilson_interval,
)
from tests.support.envs import ScriptedEnv

OBS = np.zeros(2, np.float32)


@dataclass
class Plan:
    """One scripted episode: how it ends, after how many steps, paying what per step."""

    end: str  # "success", "failure:LABEL", "failure", "truncated:REASON", "both", "none", "error"
    length: int = 3
    reward: float = 1.0
    terms: dict[str, float] = field(default_factory=dict)


def _record_plans(
    path: Path,
    plans: Sequence[Plan],
    *,
    tags: dict[str, str] | None = None,
    reports_success: bool = True,
    **kwargs: Any,
) -> Path:
    """Record ``plans``; with ``reports_success`` every final info says ``success`` (as
    Gymnasium-Robotics' ``is_success``), else only a success's does not either (CartPole)."""
    state: dict[str, Plan] = {}

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        plan = state["plan"]
        info: dict[str, Any] = {}
        if plan.terms:
            info["reward_terms"] = dict(plan.terms)
        last = env.t == plan.length
        terminated = truncated = False
        if last and plan.end == "success":
            terminated, info["success"] = True, True
        elif last and plan.end.startswith("failure"):
            terminated = True
            if ":" in plan.end:
                info["failure"] = plan.end.partition(":")[2]
        elif last and plan.end.startswith("truncated"):
            truncated, info["truncation_reason"] = True, plan.end.partition(":")[2]
        elif last and plan.end == "both":
            terminated = truncated = True
            info["failure"] = "collision"
        elif last and plan.end == "error":
            raise RuntimeError("the env broke")
        if last and reports_success:
            info["success"] = plan.end == "success"
        elif last and plan.end == "success":
            raise AssertionError("a success is reported")
        return OBS, plan.reward, terminated, truncated, info

    with RecordEvidence(ScriptedEnv(step_fn=step), path, tags=tags, **kwargs) as env:
        for seed, plan in enumerate(plans):
            state["plan"] = plan
            env.reset(seed=seed)
            for _ in range(plan.length):
                try:
                    env.step(0)
                except RuntimeError:  # Plan("error"): the episode is recorded as an error
                    break
    return path


def _one(result: Report) -> GroupReport:
    (group,) = result.groups
    return group


@pytest.mark.parametrize(
    ("successes", "n", "low", "high"),
    [
        (8, 10, 0.4902, 0.9433),
        (0, 10, 0.0, 0.2775),
        (10, 10, 0.7225, 1.0),
        (50, 100, 0.4038, 0.5962),
        (1, 1, 0.2065, 1.0),
    ],
)
def test_wilson_interval_known_values(successes: int, n: int, low: float, high: float) -> None:
    ci = wilson_interval(successes, n)
    assert ci.low == pytest.approx(low, abs=5e-5)
    assert ci.high == pytest.approx(high, abs=5e-5)
    assert 0.0 <= ci.low <= successes / n <= ci.high <= 1.0


def test_wilson_interval_other_z_and_bad_input() -> None:
    narrow = wilson_interval(8, 10, z=1.0)
    wide = wilson_interval(8, 10)
    assert wide.low < narrow.low < 0.8 < narrow.high < wide.high
    with pytest.raises(ValueError, match="Expect 0 <= successes <= n and n >= 1"):
        wilson_interval(11, 10)


def test_counts_and_rates_keep_outcomes_apart(tmp_path: Path) -> None:
    plans = [
        Plan("success", reward=2.0),
        Plan("success", reward=2.0),
        Plan("failure:collision", length=2),
        Plan("failure", length=4),
        Plan("truncated:budget", length=5),
        Plan("both", length=1),
        Plan("none", length=2),  # reset before the end: incomplete
    ]
    path = _record_plans(tmp_path / "mixed.mcap", plans)
    group = _one(report([path]))
    assert group.key == str(path)
    assert group.episodes == 7
    assert group.ended == 6
    assert group.success == 2
    assert group.failures == {"collision": 2, "unlabeled": 1}
    assert group.truncations == {"budget": 1}
    assert group.incomplete == 1 and group.errors == 0
    assert group.terminated_and_truncated == 1
    assert group.success_rate == pytest.approx(2 / 6)
    assert group.failure_rate == pytest.approx(3 / 6)
    assert group.truncation_rate == pytest.approx(1 / 6)
    assert group.success_ci == wilson_interval(2, 6)
    # every rate has its interval (PRODUCT: rates side by side, with intervals)
    assert group.failure_ci == wilson_interval(3, 6)
    assert group.truncation_ci == wilson_interval(1, 6)
    # returns and lengths over the six ended episodes only
    returns = [6.0, 6.0, 2.0, 4.0, 5.0, 1.0]
    lengths = [3, 3, 2, 4, 5, 1]
    assert group.return_mean == pytest.approx(np.mean(returns))
    assert group.return_std == pytest.approx(np.std(returns))
    assert group.length_mean == pytest.approx(np.mean(lengths))
    assert group.length_std == pytest.approx(np.std(lengths))


def test_error_episodes_are_counted_apart(tmp_path: Path) -> None:
    def step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        if env.t == 2:
            raise RuntimeError("boom")
        return OBS, 1.0, False, False, {}

    path = tmp_path / "error.mcap"
    with RecordEvidence(ScriptedEnv(step_fn=step), path) as env:
        env.reset(seed=0)
        env.step(0)
        with pytest.raises(RuntimeError):
            env.step(0)
    group = _one(report([path]))
    assert (group.episodes, group.ended, group.errors) == (1, 0, 1)
    assert group.success_rate is None and group.success_ci is None
    assert group.failure_rate is None and group.truncation_rate is None
    assert group.return_mean is None and group.length_std is None


def test_by_variants(tmp_path: Path) -> None:
    a = _record_plans(
        tmp_path / "a.mcap",
        [Plan("success"), Plan("failure:collision"), Plan("truncated:budget")],
        tags={"policy": "ppo"},
    )
    b = _record_plans(tmp_path / "b.mcap", [Plan("failure:drop"), Plan("failure:collision")])
    c = tmp_path / "c.mcap"
    with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=3), c) as env:
        env.reset(seed=0)
        for _ in range(3):
            env.step(0)

    by_file = report([b, a, c])
    assert [g.key for g in by_file.groups] == sorted([str(a), str(b), str(c)])
    assert by_file.by == "file"

    by_env = report([a, b, c], by="env")
    assert [(g.key, g.episodes) for g in by_env.groups] == [("(none)", 5), ("CartPole-v1", 1)]

    by_tag = report([a, b], by="tag:policy")
    assert [(g.key, g.episodes) for g in by_tag.groups] == [("(none)", 2), ("ppo", 3)]

    by_label = report([a, b, c], by="label")
    assert [(g.key, g.episodes) for g in by_label.groups] == [
        ("(success)", 1),
        ("(truncated:budget)", 1),
        ("(truncated:time_limit)", 1),
        ("collision", 2),
        ("drop", 1),
    ]
    collision = by_label.groups[3]
    assert collision.failure == 2  # (its rates, 1 and 0 by construction, are not computed)
    assert collision.failure_rate is None and collision.success_rate is None

    everything = _one(report([a, b, c], by="all"))
    assert everything.key == "all"
    assert (everything.episodes, everything.success) == (6, 1)
    assert everything.failures == {"collision": 2, "drop": 1}
    assert everything.truncations == {"budget": 1, "time_limit": 1}


@pytest.mark.parametrize("by", ["files", "tag:", "policy", ""])
def test_unknown_by_is_a_configuration_error(tmp_path: Path, by: str) -> None:
    with pytest.raises(ConfigurationError, match="by: expected 'file', 'env', 'tag:NAME'"):
        report([tmp_path / "unused.mcap"], by=by)


def test_gates_pass_and_fail_per_group(tmp_path: Path) -> None:
    good = _record_plans(tmp_path / "good.mcap", [Plan("success")] * 4 + [Plan("failure:drop")])
    bad = _record_plans(
        tmp_path / "bad.mcap",
        [
            Plan("success"),
            Plan("failure:collision"),
            Plan("failure:collision"),
            Plan("truncated:x"),
        ],
    )
    gates = Gates(
        min_success_rate=0.8,
        max_failure_rate=0.2,
        max_failure_rate_by_label={"collision": 0.1},
        max_truncation_rate=0.25,
    )
    only_good = report([good], gates=gates)
    assert only_good.passed
    assert [g.message for g in only_good.gates] == [
        f"success rate 0.80 >= 0.80 (group {good})",
        f"failure rate 0.20 <= 0.20 (group {good})",
        f"failure rate 'collision' 0.00 <= 0.10 (group {good}); no failure in these files is "
        "labelled 'collision': is the label spelt as recorded?",
        f"truncation rate 0.00 <= 0.25 (group {good})",
    ]
    assert only_good.unmatched_labels == ["collision"]
    assert only_good.notes == [
        "gate max_failure_rate:collision: no failure in these files is labelled 'collision': "
        "is the label spelt as recorded? (labels seen: 'drop')"
    ]
    both = report([good, bad], gates=gates)
    assert not both.passed and both.unmatched_labels == [] and both.notes == []
    failed = {(g.gate, g.group): g.message for g in both.gates if not g.passed}
    assert failed == {
        ("min_success_rate", str(bad)): f"success rate 0.25 < 0.80 (group {bad})",
        ("max_failure_rate", str(bad)): f"failure rate 0.50 > 0.20 (group {bad})",
        ("max_failure_rate:collision", str(bad)): (
            f"failure rate 'collision' 0.50 > 0.10 (group {bad})"
        ),
    }
    # pooled, the same episodes pass the truncation gate and miss the others
    pooled = report([good, bad], by="all", gates=Gates(max_truncation_rate=0.2))
    assert pooled.passed
    assert pooled.gates[0].message == "truncation rate 0.11 <= 0.20 (group all)"


def test_gate_messages_show_enough_digits(tmp_path: Path) -> None:
    plans = [Plan("success")] * 159 + [Plan("failure")] * 41  # 0.795
    path = _record_plans(tmp_path / "close.mcap", plans)
    result = report([path], by="all", gates=Gates(min_success_rate=0.8))
    assert result.gates[0].message == "success rate 0.795 < 0.80 (group all)"
    result = report([path], by="all", gates=Gates(max_failure_rate=0.085))
    assert result.gates[0].message == "failure rate 0.205 > 0.085 (group all)"  # (was 0.09)


def test_a_torn_file_of_an_env_without_success_reads_as_its_finished_files() -> None:
    # a torn file has no run-end record to say whether its env reports success: it was read
    # as if CartPole did, so every group of it got no_success_positive_return
    torn = Path(__file__).resolve().parents[2] / "fixtures" / "torn.mcap"
    result = report([torn], by="all", gates=Gates(min_success_rate=0.5))
    (group,) = result.groups
    assert not group.success_signal and group.warnings == []
    assert result.gates[0].message.startswith("success rate: the env reports no success")


def test_gate_without_ended_episodes_fails(tmp_path: Path) -> None:
    path = _record_plans(tmp_path / "none.mcap", [Plan("none")])
    result = report([path], by="all", gates=Gates(min_success_rate=0.5))
    assert not result.passed
    assert result.gates[0].message == "success rate: no ended episodes (group all)"


def test_bad_gate_values_are_configuration_errors() -> None:
    with pytest.raises(ConfigurationError, match="min_success_rate: expected a rate between 0"):
        Gates(min_success_rate=80)
    with pytest.raises(ConfigurationError, match=r"max_failure_rate_by_label\['x'\]: expected"):
        Gates(max_failure_rate_by_label={"x": -0.1})
    with pytest.raises(ConfigurationError, match=r"fail_on_incentive_warning: expected True or"):
        Gates(fail_on_incentive_warning="false")  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("gates", "message"),
    [
        (
            {"min_success_rate": 0.5},
            r"^gates: expected a Gates, got dict; pass e\.g\. Gates\(\*\*gates\)$",
        ),
        (0.5, r"^gates: expected a Gates, got float; pass e\.g\. Gates\(min_success_rate=0\.9\)$"),
    ],
)
def test_gates_that_are_not_gates_are_refused(tmp_path: Path, gates: Any, message: str) -> None:
    with pytest.raises(ConfigurationError, match=message):
        report([tmp_path / "unused.mcap"], gates=gates)


def test_failure_that_outearns_success_is_warned(tmp_path: Path) -> None:
    plans = [Plan("success", reward=1.0)] * 2 + [Plan("failure:collision", reward=4.0)] * 3
    path = _record_plans(tmp_path / "hack.mcap", [*plans, Plan("failure:drop", reward=0.0)])
    group = _one(report([path], by="all"))
    assert [w.code for w in group.warnings] == ["failure_outearns_success"]
    assert group.warnings[0].group == "all"
    assert group.warnings[0].message == (
        "failures labelled 'collision' earn a mean return of 12 over 3 episodes, "
        "more than successes (3 over 2 episodes)"
    )
    gated = report([path], by="all", gates=Gates(fail_on_incentive_warning=True))
    assert not gated.passed
    assert gated.gates[0].message == "1 incentive warning(s): failure_outearns_success (group all)"


def test_a_return_that_is_not_finite_is_left_out_of_the_warnings_and_noted(
    tmp_path: Path,
) -> None:
    plans = [Plan("success", reward=1.0)] * 2 + [Plan("failure:collision", reward=4.0)] * 3
    path = _record_plans(tmp_path / "nan.mcap", [*plans, Plan("success", reward=math.nan)])
    result = report([path], by="all")
    group = _one(result)
    assert [w.code for w in group.warnings] == ["failure_outearns_success"]
    assert group.warnings[0].message.endswith("more than successes (3 over 2 episodes)")
    assert group.nonfinite_returns == 1 and group.to_dict()["nonfinite_returns"] == 1
    (note,) = result.notes
    assert note.startswith(
        "group all: 1 of 6 ended episodes have a return that is not finite (NaN or infinite)"
    )


def test_truncation_that_outearns_success_is_warned(tmp_path: Path) -> None:
    plans = [Plan("success", length=2), Plan("truncated:time_limit", length=10)]
    group = _one(report([_record_plans(tmp_path / "stall.mcap", plans)]))
    assert [w.code for w in group.warnings] == ["truncation_outearns_success"]
    assert group.warnings[0].message == (
        "truncated episodes earn a mean return of 10 over 1 episodes, "
        "more than successes (2 over 1 episodes)"
    )


def test_no_warning_when_success_pays_best(tmp_path: Path) -> None:
    plans = [
        Plan("success", reward=5.0),
        Plan("failure:collision", reward=1.0),
        Plan("truncated:time_limit", length=4, reward=0.5),
    ]
    path = _record_plans(tmp_path / "fine.mcap", plans)
    group = _one(report([path]))
    assert group.warnings == []
    assert report([path], gates=Gates(fail_on_incentive_warning=True)).passed


def test_no_success_but_positive_return(tmp_path: Path) -> None:
    path = _record_plans(tmp_path / "never.mcap", [Plan("failure:collision", reward=2.0)] * 3)
    group = _one(report([path]))
    assert [w.code for w in group.warnings] == ["no_success_positive_return"]
    assert group.warnings[0].message == (
        "no episode succeeded (0 of 3 ended), yet failures earn a positive mean return "
        "of 6 over 3 episodes"
    )
    # when truncation pays more than failing, failing is not what the reward favours
    plans = [Plan("failure", reward=2.0), Plan("truncated:time_limit", length=10)]
    assert _one(report([_record_plans(tmp_path / "cartpole_like.mcap", plans)])).warnings == []
    negative = [Plan("failure:collision", reward=-1.0)]
    assert _one(report([_record_plans(tmp_path / "negative.mcap", negative)])).warnings == []


def test_no_success_warnings_for_a_task_without_success(tmp_path: Path) -> None:
    # A task whose infos never say anything about success (CartPole, Hopper: its episodes end
    # by falling) has no success to be missing or rare: the two success warnings would fire on
    # every run of it, failing --fail-on-incentive-warning for nothing.
    terms = {"alive": 1.0, "progress": 0.1}
    plans = [Plan("failure:fell", reward=1.1, terms=terms)] * 3
    silent = _record_plans(tmp_path / "silent.mcap", plans, reports_success=False)
    assert open_evidence(silent).reports_success is False
    group = _one(report([silent]))
    assert group.warnings == [] and group.success_signal is False
    assert report([silent], gates=Gates(fail_on_incentive_warning=True)).passed
    # the same episodes from a task that reports success (false each time) are warned
    told = _record_plans(tmp_path / "told.mcap", plans)
    assert open_evidence(told).reports_success is True
    group = _one(report([told]))
    assert [w.code for w in group.warnings] == ["no_success_positive_return", "shaping_dominates"]
    assert group.to_dict()["success_signal"] is True
    # grouped together: one file of the group reports success, so the group does
    together = _one(report([silent, told], by="all"))
    assert together.success_signal is True and len(together.warnings) == 2


def test_by_label_computes_no_rates_nor_warnings_and_takes_no_gates(tmp_path: Path) -> None:
    # Each label group holds one outcome: a failure label's group had 0 successes by
    # construction, was warned no_success_positive_return and failed --min-success-rate.
    terms = {"progress": 2.0, "alive": 0.1}
    plans = [Plan("success", reward=5.0)] * 2 + [Plan("failure:yanked", reward=2.1, terms=terms)]
    path = _record_plans(tmp_path / "mixed.mcap", [*plans, *plans[2:]])
    by_label = report([path], by="label")
    assert [(g.key, g.episodes) for g in by_label.groups] == [("(success)", 2), ("yanked", 2)]
    for group in by_label.groups:
        assert group.warnings == []
        assert (group.success_rate, group.failure_rate, group.truncation_rate) == (None,) * 3
        assert (group.success_ci, group.failure_ci, group.truncation_ci) == (None,) * 3
        assert group.to_dict()["success_rate"] is None
    assert by_label.groups[1].failures == {"yanked": 2} and by_label.groups[1].success == 0
    assert by_label.notes == [
        "by label: each group holds one outcome, so its success, failure and truncation rates "
        "(0 or 1 by construction) and incentive warnings (which set a group's outcomes against "
        "each other) are not computed; report by file, env, all or tag:NAME for them"
    ]
    for gates in (Gates(min_success_rate=0.5), Gates(fail_on_incentive_warning=True)):
        with pytest.raises(ConfigurationError, match=r"^gates: expected a grouping whose groups "
                           r"can hold several outcomes, actually by label"):  # fmt: skip
            report([path], by="label", gates=gates)
    # the same episodes in one group: rates and the warning stay
    failing = _record_plans(tmp_path / "failing.mcap", plans[2:] * 3)
    (group,) = report([failing], by="all").groups
    assert group.success_rate == 0.0 and group.failure_rate == 1.0
    assert [w.code for w in group.warnings] == ["no_success_positive_return", "shaping_dominates"]
    assert not report([path], by="all").notes


def test_cartpole_is_a_task_without_success(tmp_path: Path) -> None:
    path = tmp_path / "cartpole.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        for seed in range(5):
            env.reset(seed=seed)
            done = False
            while not done:
                _, _, terminated, truncated, _ = env.step(0)  # falls in ~10 steps
                done = terminated or truncated
    assert open_evidence(path).reports_success is False
    group = _one(report([path]))
    assert group.failures == {"unlabeled": 5} and group.return_mean is not None
    assert group.return_mean > 0 and group.warnings == []


def test_a_success_gate_on_a_task_without_success_says_so(tmp_path: Path) -> None:
    path = tmp_path / "cartpole.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        for seed in range(3):
            env.reset(seed=seed)
            while not env.step(0)[2]:
                pass
    result = report([path], by="env", gates=Gates(min_success_rate=0.7))
    assert not result.passed
    (gate,) = result.gates
    assert gate.gate == "min_success_rate" and not gate.passed
    assert gate.message == (
        "success rate: the env reports no success (group CartPole-v1): no episode's final "
        "info has a success key and no success_fn was given; to gate on success, record with "
        "ending_rules=EndingRules(success_fn=...) or success_keys=(...)"
    )
    # a task that reports success (never true here) gets the rate against its bound
    told = _record_plans(tmp_path / "told.mcap", [Plan("failure")] * 2)
    (gate,) = report([told], gates=Gates(min_success_rate=0.7)).gates
    assert gate.message == f"success rate 0.00 < 0.70 (group {told})"


def test_unstarted_episodes_are_left_out_of_the_counts(tmp_path: Path) -> None:
    """A vector loop that stops right after an episode ends leaves autoreset 0-step episodes."""
    path = tmp_path / "vec.mcap"
    envs = gym.make_vec(
        "CartPole-v1",
        2,
        vectorization_mode="sync",
        vector_kwargs={"autoreset_mode": gym.vector.AutoresetMode.SAME_STEP},
    )
    with RecordVectorEvidence(envs, path) as recorder:
        recorder.reset(seed=0)
        while True:  # stop as sub-env 1's episode ends: its autoreset is never stepped
            _, _, terminated, truncated, _ = recorder.step(np.array([0, 1]))
            if terminated[1] or truncated[1]:
                break
    episodes = open_evidence(path).episodes().to_pylist()
    zero = [e for e in episodes if e["length"] == 0]
    assert zero and all(e["outcome"] == "incomplete" for e in zero)
    group = _one(report([path]))
    assert group.episodes == len(episodes) - len(zero)
    assert group.incomplete == sum(
        e["outcome"] == "incomplete" and e["length"] > 0 for e in episodes
    )


def test_shaping_dominates(tmp_path: Path) -> None:
    terms = {"alive": 1.0, "progress": 0.1}
    plans = [Plan("success", reward=1.1, terms=terms)] + [
        Plan("failure:fell", reward=1.1, terms=terms, length=2)
    ] * 3
    group = _one(report([_record_plans(tmp_path / "shaped.mcap", plans)]))
    assert [w.code for w in group.warnings] == ["shaping_dominates"]
    assert group.warnings[0].message == (
        "term 'alive' supplies 91% of the absolute term mass (9 of 9.9) while the success "
        "rate is 0.25 (1 of 4 ended episodes)"
    )
    assert group.term_means == {
        "failure": {"alive": pytest.approx(2.0), "progress": pytest.approx(0.2)},
        "success": {"alive": pytest.approx(3.0), "progress": pytest.approx(0.3)},
    }
    # the same shaping with a good success rate is not a warning
    plans = [Plan("success", reward=1.1, terms=terms)] * 3 + [
        Plan("failure:fell", reward=1.1, terms=terms, length=2)
    ]
    assert _one(report([_record_plans(tmp_path / "fine.mcap", plans)])).warnings == []
    # nor where the task never ends by itself (time limit only, as HalfCheetah): no success
    # signal to be rare; one failure among them is one
    cut = [Plan("truncated:time_limit", reward=1.1, terms=terms)] * 4
    assert _one(report([_record_plans(tmp_path / "cut.mcap", cut)])).warnings == []
    one_fall = [*cut, Plan("failure:fell", reward=1.1, terms=terms)]
    group = _one(report([_record_plans(tmp_path / "fell.mcap", one_fall)]))
    assert "shaping_dominates" in [w.code for w in group.warnings]
    # a cost that takes most of the mass (a control cost) pays for nothing: not shaping
    costly = {"ctrl_cost": -1.0, "progress": 0.1}
    plans = [Plan("success", reward=-0.9, terms=costly)] + [
        Plan("failure:fell", reward=-0.9, terms=costly)
    ] * 3
    assert _one(report([_record_plans(tmp_path / "costly.mcap", plans)])).warnings == []


def test_declared_constants_count_as_terms(tmp_path: Path) -> None:
    plans = [Plan("success", reward=1.1, terms={"progress": 0.1})] + [
        Plan("failure:fell", reward=1.1, terms={"progress": 0.1}, length=2)
    ] * 3
    path = _record_plans(tmp_path / "alive.mcap", plans, constant_terms={"alive": 1.0})
    group = _one(report([path]))
    assert group.term_means["failure"] == {
        "alive": pytest.approx(2.0),
        "progress": pytest.approx(0.2),
    }
    assert [w.code for w in group.warnings] == ["shaping_dominates"]
    assert "term 'alive' supplies 91%" in group.warnings[0].message


def test_torn_file_counts_what_is_there(tmp_path: Path) -> None:
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
    episodes = open_evidence(torn).episodes()
    ended = sum(episodes["ended"].to_pylist())
    assert 1 <= ended < 6
    group = _one(report([torn]))
    assert group.episodes == episodes.num_rows
    assert group.ended == ended
    assert group.failures == {"unlabeled": ended}
    assert group.incomplete == episodes.num_rows - ended >= 1


def test_report_to_dict_is_stable_json(tmp_path: Path) -> None:
    def step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        return OBS, math.nan, env.t == 2, False, {"success": True}

    nan = tmp_path / "nan.mcap"
    with RecordEvidence(ScriptedEnv(step_fn=step), nan) as env:
        env.reset(seed=0)
        env.step(0)
        env.step(0)
    result = report([nan], by="all", gates=Gates(min_success_rate=0.5))
    data = json.loads(json.dumps(result.to_dict(), allow_nan=False))
    assert list(data) == [
        "by",
        "passed",
        "groups",
        "gates",
        "unfinished",
        "unit",
        "unmatched_labels",
        "notes",
        "reward_wrappers",
        "dropped",
    ]
    assert data["by"] == "all" and data["passed"] is True
    (group,) = data["groups"]
    assert group["key"] == "all"
    assert group["return_mean"] == "nan"
    assert group["success_ci"] == {"low": pytest.approx(0.2065, abs=1e-4), "high": 1.0}
    assert set(group) >= {
        "episodes",
        "ended",
        "success",
        "success_rate",
        "failure",
        "failures",
        "failure_rate",
        "truncated",
        "truncations",
        "truncation_rate",
        "incomplete",
        "errors",
        "terminated_and_truncated",
        "term_means",
        "warnings",
    }
    assert data["gates"] == [
        {
            "gate": "min_success_rate",
            "group": "all",
            "passed": True,
            "message": "success rate 1.00 >= 0.50 (group all)",
        }
    ]


def test_report_tables_takes_opened_evidence(tmp_path: Path) -> None:
    path = _record_plans(tmp_path / "x.mcap", [Plan("success"), Plan("failure:drop")])
    result = report_tables([("nightly", open_evidence(path))])
    assert [g.key for g in result.groups] == ["nightly"]
    assert result.gates == [] and result.passed
    assert report_tables([]).groups == []


def test_unreadable_file_raises_evidence_error(tmp_path: Path) -> None:
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"")
    with pytest.raises(EvidenceError, match="the file is empty"):
        report([garbage])


def test_interval_is_a_value() -> None:
    assert Interval(0.1, 0.2) == Interval(0.1, 0.2)


def test_the_error_rate_gate_counts_every_episode(tmp_path: Path) -> None:
    """Rates leave errors out, so 9 crashes in 10 still pass a success gate: this gate says so."""
    path = _record_plans(tmp_path / "crashy.mcap", [Plan("success")] + [Plan("error")] * 9)
    result = report([path], gates=Gates(min_success_rate=0.9, max_error_rate=0.1))
    assert _one(result).errors == 9
    assert [(g.gate, g.passed, g.message) for g in result.gates] == [
        ("min_success_rate", True, f"success rate 1.00 >= 0.90 (group {path})"),
        ("max_error_rate", False, f"error rate (of all episodes) 0.90 > 0.10 (group {path})"),
    ]
    with pytest.raises(ConfigurationError, match=r"max_error_rate: expected a rate between 0"):
        Gates(max_error_rate=1.5)


def test_gates_over_no_episodes_fail(tmp_path: Path) -> None:
    """A file that holds no episode (a recorder killed as it started) evaluates no gate: that is
    not a pass."""
    empty = tmp_path / "empty.mcap"
    with RecordEvidence(ScriptedEnv(), empty):
        pass
    assert report([empty]).passed  # no gates: nothing to fail
    result = report([empty], gates=Gates(min_success_rate=0.5))
    assert not result.passed
    assert [(g.gate, g.group, g.message) for g in result.gates] == [
        ("episodes", "-", "no episodes in these files: no gate could be checked")
    ]


def test_by_file_a_file_that_lost_all_its_episodes_fails_its_gates(tmp_path: Path) -> None:
    """Beside a file with episodes, one torn before its first chunk was no group, so its gates
    passed; one that kept an incomplete episode failed them (no ended episodes)."""
    good = _record_plans(tmp_path / "good.mcap", [Plan("success"), Plan("failure:fell")])
    lost = tmp_path / "lost.mcap"
    other = _record_plans(tmp_path / "other.mcap", [Plan("success")])  # (another run)
    lost.write_bytes(other.read_bytes()[:1500])  # (run metadata, no complete chunk)
    gates = Gates(max_failure_rate=1.0)
    result = report([good, lost], gates=gates)
    assert [(g.gate, g.group, g.passed, g.message) for g in result.gates] == [
        ("max_failure_rate", str(good), True, f"failure rate 0.50 <= 1.00 (group {good})"),
        ("episodes", str(lost), False, "no episodes in this file: no gate could be checked"),
    ]
    assert not result.passed
    assert [(g.key, g.episodes) for g in result.groups] == [(str(good), 2), (str(lost), 0)]
    assert report([good, lost]).passed  # (no gates: nothing to fail)
    # grouped otherwise, the file adds nothing to its group, whose gates are its other files'
    assert report([good, lost], by="env", gates=gates).passed


def _torn_before_its_first_chunk(path: Path) -> Path:
    """``path`` cut where its first chunk began: what a recorder killed as it started leaves
    (run metadata, no episode)."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    first = min(c.chunk_start_offset for c in summary.chunk_indexes)
    path.write_bytes(path.read_bytes()[:first])
    return path


@pytest.mark.parametrize(
    ("by", "keys"),
    [("env", ["Acrobot-v1", "CartPole-v1"]), ("tag:policy", ["ppo", "sac"])],
)
def test_a_group_whose_files_lost_all_their_episodes_is_shown_and_fails_its_gates(
    tmp_path: Path, by: str, keys: list[str]
) -> None:
    """An Acrobot file (policy ``sac``) torn before its first chunk beside a CartPole one
    (policy ``ppo``): its group was left out of the report, so its gates were never checked
    and the report passed."""
    good = tmp_path / "cartpole.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), good, tags={"policy": "ppo"}) as env:
        for seed in range(2):
            env.reset(seed=seed)
            while not any(env.step(0)[2:4]):
                pass
    lost = tmp_path / "acrobot.mcap"
    with RecordEvidence(gym.make("Acrobot-v1"), lost, tags={"policy": "sac"}) as env:
        env.reset(seed=0)
        for _ in range(5):
            env.step(0)
    _torn_before_its_first_chunk(lost)
    result = report([good, lost], by=by, gates=Gates(max_failure_rate=1.0))
    episodes = {keys[0]: 0, keys[1]: 2} if by == "env" else {keys[0]: 2, keys[1]: 0}
    assert [(g.key, g.episodes) for g in result.groups] == list(episodes.items())
    empty = next(g for g in result.groups if not g.episodes)
    assert (empty.ended, empty.success_rate, empty.failure_rate, empty.return_mean) == (
        0,
        None,
        None,
        None,
    )
    assert [(g.gate, g.group, g.passed) for g in result.gates] == [
        ("episodes", key, False) if not n else ("max_failure_rate", key, True)
        for key, n in episodes.items()
    ]
    (no_gate,) = [g.message for g in result.gates if g.gate == "episodes"]
    assert no_gate == "no episodes in this group: no gate could be checked"
    assert not result.passed
    assert [name for name, _ in result.unfinished] == [str(lost)]
    assert [g.key for g in report([good, lost], by="all").groups] == ["all"]


def test_a_tag_no_file_has_is_said(tmp_path: Path) -> None:
    """``by="tag:polcy"`` (misspelt) puts every episode in "(none)": the report says why."""
    path = _record_plans(tmp_path / "run.mcap", [Plan("success")], tags={"policy": "ppo"})
    assert report([path], by="tag:policy").notes == []
    missing = report([path], by="tag:polcy")
    assert [g.key for g in missing.groups] == ["(none)"]
    assert missing.missing_tag == "polcy"
    assert missing.notes == [
        "by tag:polcy: no file has the tag 'polcy', so every episode is in the group '(none)': "
        "is the tag spelt as recorded?"
    ]
    assert missing.to_dict()["notes"] == missing.notes


def test_rows_by_key_are_each_keys_rows_in_their_order() -> None:
    import pyarrow as pa
    import pyarrow.compute as pc

    from episode_audit.report.groups import by_key

    rng = np.random.default_rng(0)
    keys = [f"runs/file-{k:04d}.mcap" for k in rng.integers(0, 300, 3000)]
    chunks = [  # joined tables have a chunk per file
        pa.table({"key": keys[i : i + 250], "row": np.arange(i, i + 250)})
        for i in range(0, 3000, 250)
    ]
    table = pa.concat_tables(chunks)
    got = by_key(table)
    assert list(got) == list(dict.fromkeys(keys))  # (first seen first)
    for key, rows in got.items():
        want = table.filter(pc.equal(table.column("key"), key))
        assert rows.column("row").to_pylist() == want.column("row").to_pylist()
    assert by_key(table.slice(0, 0)) == {}


@pytest.mark.parametrize("jobs", [1, 2])
def test_report_inputs_counts_each_file_read_in_its_progress(tmp_path: Path, jobs: int) -> None:
    from episode_audit.report import report_inputs

    repo = Path(__file__).resolve().parents[2]
    (tmp_path / "junk.mcap").write_bytes(b"not evidence")
    done: list[int] = []
    result = report_inputs(
        [repo / "fixtures", tmp_path], jobs=jobs, progress=done.append, on_error=lambda e: None
    )
    assert sum(done) == 5 and len(result.unreadable) == 1  # (the unreadable one counts too)
