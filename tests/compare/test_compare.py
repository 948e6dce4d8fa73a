"""compare() on the reference tasks, on synthetic sides, and what it refuses."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from episode_audit import CompareGates, ConfigurationError, compare
from episode_audit.compare.groups import check_gates, compare_group
from episode_audit.compare.metrics import decide
from episode_audit.compare.sides import Side, pair
from episode_audit.rollout import record_episodes
from episode_audit.tasks import DRAWER_OPEN_ID

pytestmark = pytest.mark.mujoco
PROXY = {"proxy_reward": True}


def drawer(path: Path, policy: str, episodes: int, seed: int = 0) -> Path:
    record_episodes(
        DRAWER_OPEN_ID, path, policy=policy, episodes=episodes, seed=seed, env_kwargs=PROXY
    )
    return path


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("runs")
    return {
        "scripted": drawer(out / "scripted.mcap", "scripted", 40),
        "hacker": drawer(out / "hacker.mcap", "hacker", 40),
        "scripted_other": drawer(out / "scripted_other.mcap", "scripted", 40, seed=1000),
        "five": drawer(out / "five.mcap", "scripted", 5),
        "five_other": drawer(out / "five_other.mcap", "scripted", 5, seed=500),
    }


def test_hacker_regresses_on_success_paired_with_a_new_incentive_signature(
    runs: dict[str, Path],
) -> None:
    result = compare([runs["scripted"]], [runs["hacker"]])
    (group,) = result.groups
    metrics = {m.name: m for m in group.metrics}
    success = metrics["success_rate"]
    assert success.verdict == "regressed" and success.paired and success.pairs == 40
    assert success.test == "McNemar exact"
    assert success.interval.high < 0 < success.baseline - success.candidate  # type: ignore[operator]
    assert {w.code for w in group.new_warnings} & {
        "no_success_positive_return",
        "shaping_dominates",
    }
    assert result.verdict == "regressed" and not result.passed
    cases = {c.name: c for c in result.cases()}
    assert not cases["all/success_rate"].passed
    new = [c for name, c in cases.items() if name.startswith("all/incentive:")]
    assert new and all(c.passed and c.status == "new" for c in new)  # reported, untested
    gated = compare([runs["scripted"]], [runs["hacker"]], gates=CompareGates(
        fail_on_new_incentive_warning=True))  # fmt: skip
    (gate,) = gated.groups[0].gates
    assert gate.gate == "new_incentive_warnings" and not gate.passed
    assert gate.message.startswith(f"{len(group.new_warnings)} incentive warning(s) new")


def test_scripted_against_itself_on_other_seeds_never_regresses(runs: dict[str, Path]) -> None:
    result = compare([runs["scripted"]], [runs["scripted_other"]], rate_margin=0.15)
    (group,) = result.groups
    assert group.pairs == 0 and not any(m.paired for m in group.metrics)
    assert {m.test for m in group.metrics if m.kind == "rate"} == {"Fisher exact"}
    assert result.verdict in ("held", "inconclusive"), [(m.name, m.verdict) for m in group.metrics]
    assert result.passed
    default = compare([runs["scripted"]], [runs["scripted_other"]])
    assert default.verdict != "regressed" and default.passed


def test_five_episodes_a_side_is_underpowered_with_the_n_needed(runs: dict[str, Path]) -> None:
    result = compare([runs["five"]], [runs["five_other"]])
    assert result.verdict == "underpowered"
    success = result.groups[0].metrics[0]
    assert success.verdict == "underpowered"
    assert success.n_needed > 5 and success.mde > 0.05
    assert result.passed  # nothing regressed, no gate: not a failure


def test_gates_are_non_inferiority_on_the_interval(runs: dict[str, Path]) -> None:
    loose = CompareGates(max_success_drop=0.5, max_return_drop=100.0)
    result = compare([runs["scripted"]], [runs["scripted_other"]], gates=loose)
    assert [g.gate for g in result.groups[0].gates] == ["max_success_drop", "max_return_drop"]
    assert all(g.passed for g in result.groups[0].gates) and result.passed
    tight = CompareGates(max_success_drop=0.01, max_failure_increase_by_label={"collision": 0.01})
    missed = compare([runs["scripted"]], [runs["scripted_other"]], gates=tight)
    gates = {g.gate: g for g in missed.groups[0].gates}
    assert not gates["max_success_drop"].passed and not missed.passed
    assert "beyond 0.01" in gates["max_success_drop"].message
    assert "failure_rate:collision" in {m.name for m in missed.groups[0].metrics}
    assert missed.unmatched_labels == ["collision"]  # (a misspelt label passes: said, as report)
    assert missed.notes[0].startswith(
        "gate max_failure_increase:collision: no failure in these files is labelled "
        "'collision': is the label spelt as recorded? (labels seen: "
    )
    assert missed.to_dict()["unmatched_labels"] == ["collision"]


def test_a_library_one_side_did_not_import_is_no_version_mismatch() -> None:
    from episode_audit.compare.spec import field_mismatches

    base = [{"env_id": "CartPole-v1", "version:numpy": "2.3.0"}]
    cand = [{"env_id": "CartPole-v1", "version:numpy": "2.3.0", "version:mujoco": "3.3.0"}]
    assert field_mismatches(base, cand) == []  # (mujoco: imported by one process only)
    cand[0]["version:numpy"] = "2.4.0"
    assert [str(m) for m in field_mismatches(base, cand)] == [
        "version:numpy differs: baseline 2.3.0; candidate 2.4.0"
    ]


def test_different_tasks_need_the_flag_and_other_mismatches_come_first(
    runs: dict[str, Path], tmp_path: Path
) -> None:
    cart = tmp_path / "cart.mcap"
    record_episodes("CartPole-v1", cart, episodes=5, max_episode_steps=20)
    with pytest.raises(
        ConfigurationError, match=r"different tasks \(env_id differs.*pass different_tasks=True$"
    ):
        compare([runs["scripted"]], [cart])
    allowed = compare([runs["scripted"]], [cart], different_tasks=True)
    assert allowed.mismatches[0].field == "env_id"
    plain = tmp_path / "plain.mcap"
    record_episodes(DRAWER_OPEN_ID, plain, policy="scripted", episodes=5)
    result = compare([runs["five"]], [plain])
    assert [m.field for m in result.mismatches] == ["env_kwargs"]
    assert result.cases()[0].name == "spec/env_kwargs"


def test_time_limits_over_a_frame_skip_are_compared_too(tmp_path: Path) -> None:
    """The spec keeps a TimeLimit over a frame skip among its wrappers, and max_episode_steps
    says the registered one under it, the same on both sides: the limits still differ."""
    from episode_audit.compare.spec import mismatches
    from episode_audit.read import open_evidence
    from tests.support.limits import record_two_episodes, skipping_pendulum

    base = record_two_episodes(tmp_path / "base.mcap", skipping_pendulum(30), 5)
    cand = record_two_episodes(tmp_path / "cand.mcap", skipping_pendulum(60), 5)
    sides = [[(str(p), open_evidence(p))] for p in (base, cand)]
    assert [str(m) for m in mismatches(*sides)] == [
        "max_episode_steps differs: baseline 200 (over a multi-step wrapper: 30); candidate 200 "
        "(over a multi-step wrapper: 60)"
    ]


def test_time_limits_of_sub_envs_in_workers_are_not_compared(tmp_path: Path) -> None:
    """An AsyncVectorEnv's file records the outermost TimeLimit's limit, wherever it sat: the
    same sub-envs in a SyncVectorEnv are not said to differ, and the note says why."""
    import gymnasium as gym

    from episode_audit import RecordVectorEvidence
    from tests.support.limits import skipping_pendulum

    paths = []
    for make in (gym.vector.SyncVectorEnv, gym.vector.AsyncVectorEnv):
        path = tmp_path / f"{make.__name__}.mcap"
        with RecordVectorEvidence(make([lambda: skipping_pendulum(30)]), path) as rec:
            rec.action_space.seed(0)
            rec.reset(seed=0)
            for _ in range(31):
                rec.step(rec.action_space.sample())
        paths.append(path)
    result = compare([paths[0]], [paths[1]])
    assert result.mismatches == []
    assert result.notes[0] == (
        "time limits not compared: sub-envs ran in worker processes (the candidate's in "
        "AsyncVectorEnv), whose TimeLimits the recorder cannot all read, nor where they sat "
        "(recorded max_episode_steps: baseline 200 (over a multi-step wrapper: 30); candidate 30)"
    )


def test_a_file_on_both_sides_is_refused(runs: dict[str, Path]) -> None:
    with pytest.raises(ConfigurationError, match=r"five.mcap is on both sides: a file compared"):
        compare([runs["five_other"], runs["five"]], [runs["five"].parent / "." / "five.mcap"])


def test_by_file_is_refused(runs: dict[str, Path]) -> None:
    with pytest.raises(ConfigurationError, match="by='file'"):
        compare([runs["five"]], [runs["five"]], by="file")


def test_pairs_match_the_kth_episode_of_each_seed() -> None:
    base = Side.of(["success"] * 4, seed=[1, 1, 2, None])
    cand = Side.of(["success"] * 4, seed=[2, 1, None, 1])
    pairs = pair(base, cand)
    assert list(zip(pairs.base.tolist(), pairs.cand.tolist(), strict=True)) == [
        (2, 0),
        (0, 1),
        (1, 3),
    ]


def test_identical_sides_are_held_and_a_drop_regresses() -> None:
    outcomes = ["success"] * 90 + ["failure"] * 10
    seeds = list(range(100))
    same = compare_group(
        "g", Side.of(outcomes, seed=seeds), Side.of(outcomes, seed=seeds), CompareGates(), []
    )
    for m in same.metrics:
        m.verdict = decide(m)
    assert {m.verdict for m in same.metrics} == {"held"}
    worse = ["success"] * 60 + ["failure"] * 40
    drop = compare_group(
        "g", Side.of(outcomes, seed=seeds), Side.of(worse, seed=seeds), CompareGates(), []
    )
    success = drop.metrics[0]
    success.verdict = decide(success)
    assert success.verdict == "regressed" and success.paired


@pytest.mark.parametrize("seeds", [([1], [2]), ([1], [1])])
def test_one_episode_a_side_passes_no_gate_and_plans_no_n(
    seeds: tuple[list[int], list[int]],
) -> None:
    base = Side.of(["success"], [21.0], seed=list(seeds[0]))
    cand = Side.of(["success"], [42.0], seed=list(seeds[1]))
    group = compare_group("g", base, cand, CompareGates(max_return_drop=5.0), [])
    returns = {m.name: m for m in group.metrics}["return"]
    assert returns.interval.low == -float("inf") and returns.interval.high == float("inf")
    (gate,) = check_gates(group, CompareGates(max_return_drop=5.0))
    assert not gate.passed  # one episode cannot show a drop of at most 5
    unit = "one pair has" if returns.paired else "one episode a side has"
    assert gate.message == (
        f"return: cannot be verified, {unit} no spread to resample (at least 2 needed); "
        "record more (group g)"
    )
    returns.verdict = decide(returns)
    assert returns.verdict == "underpowered"
    assert returns.to_dict()["n_needed"] is None  # (no n is enough: no spread known)


def test_no_shared_group_is_refused_not_passed(runs: dict[str, Path]) -> None:
    # tag:policy is 'scripted' on one side and 'hacker' on the other: nothing to compare
    with pytest.raises(
        ConfigurationError, match=r"no group is on both sides \(baseline: 'scripted'"
    ):
        compare([runs["scripted"]], [runs["hacker"]], by="tag:policy")


def test_holm_adjusts_the_primary_metrics_of_all_groups_as_one_family() -> None:
    from episode_audit.compare.core import _decide
    from episode_audit.compare.stats import holm

    seeds = list(range(60))
    base = Side.of(["success"] * 50 + ["truncated"] * 10, seed=seeds)
    cand = Side.of(["success"] * 44 + ["truncated"] * 16, seed=seeds)
    groups = [compare_group(k, base, cand, CompareGates(), []) for k in ("a", "b")]
    _decide(groups)
    family = [m for g in groups for m in g.metrics if m.can_reject and not m.same_test_as]
    assert [m.name for m in family if m.better != "none"] == ["success_rate", "success_rate"]
    assert [m.p_adjusted for m in family if m.better != "none"] == holm(
        [m.p_value for m in family if m.better != "none"]
    )
    failure = next(m for m in groups[0].metrics if m.name == "failure_rate")
    assert not failure.can_reject  # (0 against 0; truncation_rate has no verdict)
    success = groups[0].metric("success_rate")
    assert success.p_value < 0.05 <= success.p_adjusted  # significant alone, not after Holm
    assert success.verdict != "regressed"


def _vector_run(path: Path, seed: int) -> Path:
    import gymnasium as gym

    from episode_audit import RecordVectorEvidence

    envs = gym.make_vec("CartPole-v1", num_envs=2, vectorization_mode="sync")
    with RecordVectorEvidence(envs, path) as rec:
        rec.reset(seed=seed)
        rec.action_space.seed(seed)
        for _ in range(300):
            rec.step(rec.action_space.sample())
    return path


def test_autoreset_episodes_pair_on_the_rng_state_they_began_from(tmp_path: Path) -> None:
    # Two identical vector runs: only each sub-env's first episode has a seed; the others
    # began from a recorded RNG state, the same on both sides.
    base, cand = (_vector_run(tmp_path / f"{name}.mcap", 7) for name in ("b", "c"))
    result = compare([base], [cand], by="env_index", gates=CompareGates(max_return_drop=5.0))
    for group in result.groups:
        returns = {m.name: m for m in group.metrics}["return"]
        assert returns.paired and returns.pairs == returns.baseline_n > 5
        assert returns.interval.low == returns.interval.high == 0.0
    assert all(g.passed for group in result.groups for g in group.gates)
    other = _vector_run(tmp_path / "other.mcap", 8)  # other seeds: other states, no pairs
    unpaired = compare([base], [other], by="env_index")
    assert all(not m.paired for g in unpaired.groups for m in g.metrics)


def test_two_constant_episodes_a_side_are_not_a_regression() -> None:
    from episode_audit.compare.core import _decide

    group = compare_group(
        "g", Side.of(["success"] * 2, [1.0, 1.0]), Side.of(["success"] * 2, [0.0, 0.0]),
        CompareGates(), [],
    )  # fmt: skip
    _decide([group])
    returns = {m.name: m for m in group.metrics}["return"]
    assert returns.p_value == pytest.approx(1 / 3)
    assert returns.verdict == "underpowered" and group.verdict != "regressed"
    assert returns.n_needed == 4  # (the fewest a side whose exact test can reach p < 0.05)


def test_a_t_test_on_too_few_episodes_to_bound_the_difference_decides_nothing() -> None:
    """3 a side: Welch's t gives p = 2e-5 for this drop, but no exact test can reject with 3
    (its smallest p is 0.1) and the interval is unbounded: `regressed` next to (-inf, inf)."""
    from episode_audit.compare.core import _decide

    base = Side.of(["success"] * 3, [10.0, 10.1, 9.9])
    cand = Side.of(["success"] * 3, [5.0, 5.1, 4.9])
    group = compare_group("g", base, cand, CompareGates(), [])
    _decide([group])
    returns = group.metric("return")
    assert returns.p_value < 0.001 and returns.interval.low == -math.inf
    assert returns.verdict == "underpowered" and group.verdict != "regressed"
    more = compare_group(  # 4 a side: an exact test can reject, the t-test's verdict stands
        "g", Side.of(["success"] * 4, [10.0, 10.1, 9.9, 10.0]),
        Side.of(["success"] * 4, [5.0, 5.1, 4.9, 5.0]), CompareGates(), [],
    )  # fmt: skip
    _decide([more])
    assert more.metric("return").verdict == "regressed"


def test_null_with_two_episodes_a_side_of_discrete_returns_is_never_decided() -> None:
    """Returns of 0 or 1, both sides alike: sides without spread are common, and no evidence."""
    from episode_audit.compare.core import _decide

    rng = np.random.default_rng(1)
    verdicts = []
    for _ in range(300):
        sides = [Side.of(["success"] * 2, list(rng.integers(0, 2, 2) * 1.0)) for _ in "bc"]
        group = compare_group("g", *sides, CompareGates(), [])
        _decide([group])
        verdicts.append({m.name: m for m in group.metrics}["return"].verdict)
    assert verdicts.count("regressed") == verdicts.count("improved") == 0


def test_holm_counts_each_hypothesis_once() -> None:
    """One failure label and no truncation: success, failure and the label's rate are one
    test; a 0-against-0 truncation rate and constant returns cannot reject, so none counts."""
    from episode_audit.compare.core import _decide

    def side(successes: int) -> Side:
        outcome = ["success"] * successes + ["failure"] * (40 - successes)
        labels = [None] * successes + ["slipped"] * (40 - successes)
        return Side.of(outcome, failure_label=labels)

    group = compare_group("g", side(32), side(22), CompareGates(), [])
    _decide([group])
    m = {x.name: x for x in group.metrics}
    success = m["success_rate"]
    assert success.p_value == pytest.approx(0.0307, abs=1e-4)
    assert success.p_adjusted == success.p_value  # a family of one, not of five
    assert success.verdict == "regressed"
    assert [x.name for x in group.metrics if x.can_reject and x.same_test_as is None] == [
        "success_rate"
    ]
    assert m["failure_rate"].same_test_as == m["failure_rate:slipped"].same_test_as
    assert m["failure_rate"].same_test_as == "success_rate"
    assert not m["truncation_rate"].can_reject and not m["return"].can_reject
    assert m["failure_rate:slipped"].p_adjusted == success.p_adjusted
    assert m["truncation_rate"].p_adjusted is None  # (no direction, no verdict)
    assert group.metric("failure_rate").to_dict()["same_test_as"] == "success_rate"


def test_a_return_that_is_not_finite_is_said_and_not_tested() -> None:
    from episode_audit.compare.core import Comparison, _decide

    rng = np.random.default_rng(3)
    returns = list(rng.normal(5.0, 1.0, 30))
    group = compare_group(
        "g", Side.of(["success"] * 30, [*returns[:29], math.nan]),
        Side.of(["success"] * 30, returns), CompareGates(), [],
    )  # fmt: skip
    _decide([group])
    assert group.metric("return").verdict == "inconclusive"  # (more episodes would not help)
    (note,) = Comparison("all", [], [group]).notes
    assert note.startswith(
        "group g: 1 of 30 baseline and 0 of 30 candidate episodes have a return that is not "
        "finite (NaN or infinite): the mean return is undefined, so it is not tested"
    )
    assert group.to_dict()["notes"] == group.notes


def test_a_gate_message_shows_the_digits_where_value_and_limit_differ() -> None:
    side = Side.of(["success"] * 10)  # 0 of 10 failures a side: the interval's end is 0.27753
    gates = CompareGates(max_failure_increase=0.2775)
    (gate,) = check_gates(compare_group("g", side, side, gates, []), gates)
    assert "allows an increase of up to 0.27753, beyond 0.2775 (group g)" in gate.message


def test_compare_inputs_counts_each_file_read_in_its_progress(tmp_path: Path) -> None:
    from episode_audit.compare import compare_inputs

    repo = Path(__file__).resolve().parents[2]
    done: list[int] = []
    compare_inputs(
        [repo / "fixtures" / "clean.mcap"],
        [repo / "fixtures" / "unlabeled_failure.mcap"],
        different_tasks=True,
        progress=done.append,
    )
    assert sum(done) == 2


def test_an_env_that_reports_no_success_has_no_success_metric_and_fails_its_gate(
    tmp_path: Path,
) -> None:
    # CartPole's success rate is 0 on both sides by construction: "held" was no verdict
    base, cand = tmp_path / "base.mcap", tmp_path / "cand.mcap"
    record_episodes("CartPole-v1", base, episodes=6, seed=0)
    record_episodes("CartPole-v1", cand, episodes=6, seed=0)
    result = compare([base], [cand], gates=CompareGates(max_success_drop=0.1))
    (group,) = result.groups
    assert "success_rate" not in [m.name for m in group.metrics]
    (gate,) = group.gates
    assert (gate.gate, gate.passed) == ("max_success_drop", False)
    assert gate.message.startswith("success_rate: the env reports no success (group all)")
    assert not result.passed


def _constant_runs(path: Path, episodes: int, steps: int, seed: int = 0) -> Path:
    """CartPole episodes cut at ``steps`` before the pole can fall: each returns ``steps``."""
    import gymnasium as gym

    from episode_audit import RecordEvidence

    with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=steps), path) as env:
        for i in range(episodes):
            env.reset(seed=seed + i)
            truncated = False
            while not truncated:
                truncated = env.step(i % 2)[3]
    return path


@pytest.mark.parametrize(
    ("base_seed", "why"),
    [
        (0, "2 pairs are too few: an exact test's p is at least 0.5 (6 pairs can reach"),
        (100, "2 episodes a side are too few: an exact test's p is at least 0.333 (4 a side"),
    ],
)
def test_two_constant_episodes_a_side_pass_no_return_gate(
    tmp_path: Path, base_seed: int, why: str
) -> None:
    # returns [5, 5] against [5, 5] had the interval [0, 0]: any --max-return-drop passed
    base = _constant_runs(tmp_path / "base.mcap", 2, 5, seed=base_seed)
    cand = _constant_runs(tmp_path / "cand.mcap", 2, 5)
    result = compare([base], [cand], gates=CompareGates(max_return_drop=0.5))
    (group,) = result.groups
    returns = group.metric("return")
    assert (returns.baseline, returns.candidate, returns.paired) == (5.0, 5.0, base_seed == 0)
    assert returns.interval.low == -math.inf and returns.interval.high == math.inf
    assert returns.verdict == "underpowered"
    (gate,) = group.gates
    assert not gate.passed and not result.passed
    assert gate.message.startswith(f"return: cannot be verified, {why}")
    (note,) = result.notes
    assert note.startswith(f"group all: return: {why}")
    assert note.endswith(
        "so the difference has no 95 % interval and a max_return_drop gate cannot be verified: "
        "record more episodes"
    )


def test_constant_returns_on_enough_pairs_are_still_decided(tmp_path: Path) -> None:
    # 6 pairs without spread: the sign test's p = 2/64 rejects every shift but the one seen
    base = _constant_runs(tmp_path / "base.mcap", 6, 5)
    same = compare([base], [_constant_runs(tmp_path / "same.mcap", 6, 5)],
                   gates=CompareGates(max_return_drop=0.5))  # fmt: skip
    assert same.groups[0].metric("return").verdict == "held" and same.passed
    assert not same.notes
    short = _constant_runs(tmp_path / "short.mcap", 6, 3)  # returns 3: a drop of 2
    worse = compare([base], [short], gates=CompareGates(max_return_drop=1.0))
    returns = worse.groups[0].metric("return")
    assert (returns.interval.low, returns.interval.high) == (-2.0, -2.0)
    assert returns.verdict == "regressed"
    assert worse.groups[0].gates[0].message == (
        "return: the 95 % interval allows a drop of up to 2, beyond 1 (group all)"
    )


def test_an_unlabelled_failure_is_named_as_report_names_it(tmp_path: Path) -> None:
    # A file whose failures carry no label (null: another writer's) showed `failure_rate:None`
    # at 0 against 0, and `failure_rate:unlabeled` regressed from 0 to 1 on the same failures.
    from episode_audit import report
    from tests.support.hostile import replace_column, rewrite

    source, cand = tmp_path / "source.mcap", tmp_path / "cand.mcap"
    for path in (source, cand):
        record_episodes("CartPole-v1", path, episodes=8, seed=0)  # (every episode falls)
    base = rewrite(source, tmp_path / "base.mcap", episodes=lambda batch: replace_column(
        batch, "failure_label", [None] * batch.num_rows))  # fmt: skip
    (group,) = report([base]).groups
    assert group.failures == {"unlabeled": 8}
    result = compare([base], [cand])
    rates = {m.name: m for m in result.groups[0].metrics if m.kind == "rate"}
    assert list(rates) == ["failure_rate", "failure_rate:unlabeled", "truncation_rate"]
    unlabeled = rates["failure_rate:unlabeled"]
    assert (unlabeled.baseline, unlabeled.candidate, unlabeled.pairs) == (1.0, 1.0, 8)
    assert unlabeled.same_test_as is None and not unlabeled.can_reject  # (was: p 0.0078)
    assert result.verdict != "regressed" and result.seen_labels == ["unlabeled"]
    empty = Side.of(["failure", "failure"], failure_label=[None, ""])
    names = [m.name for m in compare_group("g", empty, empty, CompareGates(), []).metrics]
    assert [n for n in names if n.startswith("failure_rate:")] == ["failure_rate:unlabeled"]
