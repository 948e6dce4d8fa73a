"""A command's inputs (read/inputs.py): how folders are searched, symbolic links included."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from episode_audit import ConfigurationError, EvidenceError, open_evidence
from episode_audit.read import evidence_files, steps_total
from episode_audit.read.inputs import listed_inputs
from tests.read.helpers import record_cartpole


@pytest.fixture(scope="module")
def linked(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``top/`` holds a file, a link to the folder ``real/`` (two files, and a link back up to
    ``top/``), a link to itself's parent, a link whose target is gone and a link to itself."""
    root = tmp_path_factory.mktemp("links")
    (root / "real").mkdir()
    (root / "top").mkdir()
    record_cartpole(root / "real" / "a.mcap", episodes=1)
    shutil.copy(root / "real" / "a.mcap", root / "real" / "b.mcap")
    shutil.copy(root / "real" / "a.mcap", root / "top" / "c.mcap")
    os.symlink("../real", root / "top" / "linked")
    os.symlink("../top", root / "real" / "back")  # (a loop through two folders)
    os.symlink("..", root / "top" / "up")
    os.symlink("../real/moved-away.mcap", root / "top" / "dangling.mcap")
    os.symlink("loop.mcap", root / "top" / "loop.mcap")
    return root


def test_a_folder_search_follows_linked_folders_and_lists_links_that_lead_nowhere(
    linked: Path,
) -> None:
    # the linked folder was not searched, and the two links were skipped without a word
    top = linked / "top"
    assert evidence_files([top]) == [
        top / "c.mcap",
        top / "dangling.mcap",
        top / "linked" / "a.mcap",
        top / "linked" / "b.mcap",
        top / "loop.mcap",
    ]
    with pytest.raises(EvidenceError, match=r"dangling\.mcap: cannot open: broken symbolic link "
                       r"\(to \.\./real/moved-away\.mcap, which does not exist\)$"):  # fmt: skip
        open_evidence(top / "dangling.mcap")
    with pytest.raises(EvidenceError, match=r"loop\.mcap: cannot open: symbolic link loop$"):
        open_evidence(top / "loop.mcap")


def test_a_file_reached_through_a_link_and_its_folder_counts_once(linked: Path) -> None:
    real, top = linked / "real", linked / "top"
    found = evidence_files([real, top])
    assert found[:2] == [real / "a.mcap", real / "b.mcap"]
    assert sorted(map(os.path.realpath, found)) == sorted(set(map(os.path.realpath, found)))
    assert len(found) == 5  # (a, b, c, and the two links that lead nowhere)


@pytest.mark.parametrize(
    ("name", "why"),
    [
        ("loop.mcap", "symbolic link loop"),
        ("dangling.mcap", r"broken symbolic link \(to \.\./real/moved-away\.mcap, which does "),
    ],
)
def test_a_link_named_that_leads_nowhere_says_so(linked: Path, name: str, why: str) -> None:
    # a link loop said "no such file or directory"
    with pytest.raises(ConfigurationError, match=rf"top/{name}: {why}"):
        evidence_files([linked / "top" / name])


@pytest.fixture(scope="module")
def finished(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return record_cartpole(tmp_path_factory.mktemp("steps") / "finished.mcap", episodes=20)


def _torn(finished: Path, to: Path, part: float = 0.5) -> Path:
    """A copy of ``finished`` cut at ``part`` of its bytes, as a crash leaves a file."""
    data = finished.read_bytes()
    to.write_bytes(data[: int(len(data) * part)])
    return to


def test_a_torn_file_s_steps_are_estimated_from_its_size(finished: Path, tmp_path: Path) -> None:
    # one torn file among many removed the progress bar's total (and its time left)
    declared = open_evidence(finished).run_end
    assert declared is not None
    steps = int(declared["steps"])
    torn = _torn(finished, tmp_path / "torn.mcap")
    total = steps_total([finished, torn])
    assert total is not None
    assert steps * 1.4 <= total <= steps * 1.6  # (half its bytes: about half its steps)
    assert steps_total([torn]) is None  # (no file says how many steps a byte holds)


def test_an_unreadable_file_counts_no_steps(finished: Path, tmp_path: Path) -> None:
    # it removed the total too
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    declared = open_evidence(finished).run_end
    assert declared is not None
    assert steps_total([finished, empty]) == int(declared["steps"])


@pytest.fixture(scope="module")
def with_export(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``runs/`` holds a CartPole recording and, in ``viewer/``, its Foxglove export."""
    from episode_audit.export import export

    runs = tmp_path_factory.mktemp("exports") / "runs"
    (runs / "viewer").mkdir(parents=True)
    record_cartpole(runs / "run.mcap", episodes=2)
    export([runs / "run.mcap"], runs / "viewer" / "run.foxglove.mcap", to="foxglove")
    return runs


def test_a_folder_s_viewer_exports_are_left_out_and_listed(with_export: Path) -> None:
    """The export was listed as an input, which then could not be read (not evidence)."""
    export = with_export / "viewer" / "run.foxglove.mcap"
    inputs = listed_inputs([with_export])
    assert (inputs.files, inputs.exports) == ([with_export / "run.mcap"], [export])
    assert inputs.exports_note() == (
        f"left out 1 viewer export(s) found in the directories given ({export})"
    )
    assert evidence_files([with_export]) == [with_export / "run.mcap"]
    # named, it is an input, and opening it says what it is
    named = listed_inputs([export, with_export])
    assert (named.files, named.exports) == ([export, with_export / "run.mcap"], [export])
    with pytest.raises(EvidenceError, match=r"Foxglove export of .* \(a viewer file\), not evid"):
        open_evidence(export)
    with pytest.raises(ConfigurationError, match=r"viewer: no evidence files in this directory: "):
        listed_inputs([with_export / "viewer"])
    assert listed_inputs([with_export / "run.mcap"]).exports == []
