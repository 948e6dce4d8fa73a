"""report over files recorded over reward wrappers: it says whose returns it tabulates."""

from __future__ import annotations

from pathlib import Path

import pytest

from episode_audit.report import report_inputs, write_report_html
from episode_audit.report.wrapped import Wrapped
from tests.support.rewards import record_cartpole


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("wrapped")
    return {w: record_cartpole(out / f"{w}.mcap", w) for w in ("plain", "normalized", "scaled")}


def test_report_says_the_returns_are_the_wrappers_naming_them_and_the_files(
    files: dict[str, Path],
) -> None:
    result = report_inputs(list(files.values())).report
    by_file = {Path(g.key).stem: g for g in result.groups}
    # what the file holds: TransformReward's rewards (x10), the env's are the lengths
    assert by_file["scaled"].return_mean == pytest.approx(10 * by_file["scaled"].length_mean)
    assert by_file["plain"].return_mean == pytest.approx(by_file["plain"].length_mean)
    assert result.reward_note == (
        "2/3 files' returns are not the env's: NormalizeReward, TransformReward"
    )
    assert result.to_dict()["reward_wrappers"] == [
        {"wrappers": ["NormalizeReward"], "files": 1},
        {"wrappers": ["TransformReward"], "files": 1},
    ]
    assert result.reward_note not in result.notes  # (said once: not on stderr too)


def test_a_report_of_the_envs_own_rewards_says_nothing(files: dict[str, Path]) -> None:
    result = report_inputs([files["plain"]]).report
    assert result.reward_note is None and result.to_dict()["reward_wrappers"] == []


def test_the_html_page_says_it_among_its_notes(files: dict[str, Path], tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    result = report_inputs([files["plain"], files["normalized"]], by="all")
    page = write_report_html(result.report, result.parts, tmp_path / "r.html").read_text()
    notes = page[page.index('<ul class="notes">') : page.index("<h2>Outcomes</h2>")]
    assert "<li>1/2 files&#x27; returns are not the env&#x27;s: NormalizeReward</li>" in notes


@pytest.mark.parametrize(
    ("wrapped", "side", "note"),
    [
        (Wrapped(5, {("ClipReward",): 3}), "", "3/5 files' returns are not the env's: ClipReward"),
        (
            Wrapped(2, {("NormalizeReward", "TransformReward"): 2}),
            "candidate",
            "Candidate 2/2 files' returns are not the env's: NormalizeReward+TransformReward",
        ),
        (
            Wrapped(2000, {("NormalizeReward", "TransformReward"): 1999, ("ClipReward",): 1}),
            "baseline",
            "Baseline 2000/2000 files' returns are not the env's: NormalizeReward+TransformR…",
        ),
    ],
)
def test_the_note_names_the_chains_most_files_first_in_80_columns(
    wrapped: Wrapped, side: str, note: str
) -> None:
    assert wrapped.note(side) == note and len(note) <= 80


def test_a_group_of_files_over_different_reward_wrappers_has_no_return_to_mix(
    files: dict[str, Path],
) -> None:
    # by all: x10 returns beside the env's would average to a number of no unit, and the
    # incentive warnings would compare failures of one file with successes of another
    result = report_inputs([files["plain"], files["scaled"]], by="all").report
    (group,) = result.groups
    assert group.mixed_rewards
    assert (group.return_mean, group.return_std) == (None, None)
    assert group.to_dict()["return_mean"] is None
    assert group.length_mean is not None and group.failure_rate is not None
    assert result.notes == [
        "group all: its files were recorded over different reward wrappers or settings (or "
        "some over none), so its returns are in different units: no return mean, and no "
        "incentive warning that compares returns"
    ]
    same = report_inputs([files["scaled"], files["scaled"]], by="all").report
    assert not same.groups[0].mixed_rewards and same.groups[0].return_mean is not None
    assert same.notes == []


def test_a_group_of_files_over_one_wrapper_set_up_otherwise_has_no_return_to_mix(
    tmp_path: Path,
) -> None:
    # ClipReward to 1 and to 0.5: the same wrapper, returns in different units
    paths = [record_cartpole(tmp_path / f"{w}.mcap", w) for w in ("clipped", "clipped_half")]
    (group,) = report_inputs(paths, by="all").report.groups
    assert group.mixed_rewards and group.return_mean is None
    again = record_cartpole(tmp_path / "again.mcap", "clipped")
    (same,) = report_inputs([paths[0], again], by="all").report.groups
    assert not same.mixed_rewards and same.return_mean is not None
