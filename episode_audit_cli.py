"""The ``episode-audit`` command's entry point, outside the package.

Importing :mod:`episode_audit` (Gymnasium, pyarrow, MuJoCo) takes about a second, and the
command's own Ctrl-C handling (one line on stderr, exit 130) starts only once it has. The
command imports it here instead, where a Ctrl-C during the import is that same line and exit
code, not a traceback.
"""

from __future__ import annotations

import sys

__all__ = ["main"]

EXIT_INTERRUPTED = 130


def main() -> None:
    """Import the command and run it (``episode_audit.cli.main``)."""
    try:
        from episode_audit.cli import main as command
    except KeyboardInterrupt:
        print("episode-audit: error: interrupted (Ctrl-C): stopped", file=sys.stderr)
        raise SystemExit(EXIT_INTERRUPTED) from None
    command()


if __name__ == "__main__":
    main()
