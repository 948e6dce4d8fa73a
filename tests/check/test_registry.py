from __future__ import annotations

from pathlib import Path

import pytest

from episode_audit.check import FINDING_CODES, KINDS, kind_of, registry
from episode_audit.check.docs import findings_markdown

DOCS = Path(__file__).parents[2] / "docs" / "findings.md"


def test_docs_findings_md_is_what_the_registry_generates() -> None:
    """Regenerate with ``python -m episode_audit.check.docs > docs/findings.md``."""
    assert DOCS.read_text() == findings_markdown()


def test_every_code_constant_is_in_the_registry_once() -> None:
    constants = {
        value for name, value in vars(registry).items() if name.isupper() and isinstance(value, str)
    }
    assert constants == set(FINDING_CODES)
    assert len(FINDING_CODES) == len(set(FINDING_CODES)) == len(KINDS)


@pytest.mark.parametrize("kind", KINDS, ids=lambda k: k.code)
def test_every_entry_says_what_why_and_how(kind: registry.FindingKind) -> None:
    assert kind.severity in registry.SEVERITY_RANK
    for text in (kind.summary, kind.meaning, kind.why, kind.fix):
        assert text.strip() and "\n" not in text, kind.code
    assert kind.summary.endswith(".") and len(kind.summary) <= 80, kind.code


def test_a_recorder_note_is_the_recorder_note_entry() -> None:
    assert kind_of("recorder_note:observation_cast") is kind_of("recorder_note")
    assert kind_of("missing_terms").severity == "warning"
    for unknown in ("recorder_note:", "missing_term", "recorder_notes:x"):
        with pytest.raises(KeyError):
            kind_of(unknown)
