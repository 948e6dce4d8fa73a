"""The ``episode-audit`` command: a thin Typer layer over the library (see ``docs/cli.md``)."""

from ._app import app, main

__all__ = ["app", "main"]
