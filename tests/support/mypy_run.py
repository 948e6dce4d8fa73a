"""mypy run on a user's snippet, as a user's type checker sees the package."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path


def mypy_output(tmp_path: Path, code: str) -> str:
    """mypy --strict's report on ``code`` (its imports followed silently, the cache shared)."""
    snippet = tmp_path / "snippet.py"
    snippet.write_text(textwrap.dedent(code))
    return subprocess.run(
        [sys.executable, "-m", "mypy", "--strict", "--follow-imports=silent", str(snippet)],
        capture_output=True,
        text=True,
        check=False,
    ).stdout
