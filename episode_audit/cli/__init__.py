"""The ``episode-audit`` command: a thin Typer layer over the library (see ``docs/cli.md``).

:mod:`._app` holds the Typer app and what every command shares (inputs, progress, exit codes);
each command is a module of its own, registered on the app when imported here, in the order
``--help`` lists them; :mod:`.render` turns results into tables, Markdown or JSON.
"""

from . import check, replay, report, compare, show, export, recover, record  # noqa: F401, I001 - the order of --help
from ._app import app, main

__all__ = ["app", "main"]
