"""The Foxglove layout of an export, as the Foxglove app imports it (*Import from file…*).

The app imports a layout in the shape it exports one: ``configById`` (each panel's settings,
keyed by its id ``TYPE!NAME``), ``layout`` (the tree of splits, each ``first`` / ``second`` a
panel id or a split), ``globalVariables``, ``userNodes`` and ``playbackConfig``. (The
``foxglove.layouts`` classes of foxglove-sdk build another shape, ``{"version": 1, "content":
…}``, for its notebook viewer's ``layout=``; the viewer takes the app's as ``opaque_layout=``.)

:func:`foxglove_layout` builds it for one stream's topics: plots of ``reward`` and of the
reward terms, episode boundaries and ``terminated`` / ``truncated`` as state transitions, the
current step's message, the camera image and the ending log (``/log``).
:func:`foxglove_layout_of` builds it from what an export wrote: its topics, its reward terms.
``docs/foxglove-layout.json`` is :func:`foxglove_layout` for the reference tasks; on the command
line::

    python -m episode_audit.export.layout > docs/foxglove-layout.json
    python -m episode_audit.export.layout viewers/run.foxglove.mcap > run.layout.json
"""

from __future__ import annotations

import argparse
import json
import os
import re
import struct
import sys
from collections.abc import Sequence
from typing import Any, Final

from ..errors import ConfigurationError, EpisodeAuditError
from ..format import names as fmt

__all__ = ["REFERENCE_TERMS", "foxglove_layout", "foxglove_layout_of", "main"]

REFERENCE_TERMS: Final = (
    "shaping",
    "progress_velocity",
    "ctrl_cost",
    "failure_penalty",
    "success_bonus",
)
"""The reward terms of the reference tasks (``episode_audit.tasks``, both reward modes)."""

LOG_TOPIC: Final = "/log"
_STEP_SCHEMA: Final = "episode_audit.Step"
_IMAGE_SCHEMA: Final = "foxglove.CompressedImage"
_PLOT: Final = {  # the settings the app writes for a new Plot panel
    "showXAxisLabels": True,
    "showYAxisLabels": True,
    "showLegend": True,
    "legendDisplay": "floating",
    "showPlotValuesInLegend": False,
    "isSynced": True,
    "xAxisVal": "timestamp",
    "sidebarDimension": 240,
}


def _quoted(name: str, allowed: str) -> str:
    """``name`` in a message path: as it is if it holds only ``allowed``, else quoted.

    Foxglove's own rule (``quoteTopicNameIfNeeded`` / ``quoteFieldNameIfNeeded``).

    >>> _quoted("/env_0/steps", "a-zA-Z0-9_/-"), _quoted("/p.1/steps", "a-zA-Z0-9_/-")
    ('/env_0/steps', '"/p.1/steps"')
    """
    if re.fullmatch(f"[{allowed}]+", name):
        return name
    return '"' + re.sub(r'([\\"])', r"\\\1", name) + '"'


def _path(topic: str, *fields: str) -> str:
    """A message path: ``topic`` then ``fields``, each quoted where Foxglove needs it.

    >>> _path("/steps", "terms", "ctrl cost")
    '/steps.terms."ctrl cost"'
    """
    return _quoted(topic, "a-zA-Z0-9_/-") + "".join("." + _quoted(f, "a-zA-Z0-9_-") for f in fields)


def _series(path: str, label: str, *, plot: bool = True) -> dict[str, Any]:
    series: dict[str, Any] = {"value": path}
    if plot:
        series["enabled"] = True
    series |= {"timestampMethod": "receiveTime", "label": label}
    return series


def _split(direction: str, first: Any, second: Any, percent: float) -> dict[str, Any]:
    return {"first": first, "second": second, "direction": direction, "splitPercentage": percent}


def foxglove_layout(
    terms: Sequence[str] = REFERENCE_TERMS,
    *,
    prefix: str = "",
    image_topic: str | None = "",
) -> str:
    """The layout as JSON for Foxglove's *Import from file…*, for one stream's topics.

    ``prefix`` is the stream's topic prefix (``"/env_0"``, ``"/player_1"``; empty for
    single-env files); ``terms`` the reward terms to plot, one series each; ``image_topic``
    the camera topic the Image panel shows: ``""`` (default) the stream's
    ``camera/observation``, ``None`` no Image panel (the export has no camera).
    """
    steps = f"{prefix}/steps"
    if image_topic == "":
        image_topic = f"{prefix}/camera/observation"
    config: dict[str, dict[str, Any]] = {
        "Plot!reward": {
            "paths": [_series(_path(steps, "reward"), "reward")],
            **_PLOT,
            "foxglovePanelTitle": "reward",
        },
        "Plot!terms": {
            "paths": [_series(_path(steps, "terms", t), t) for t in terms],
            **_PLOT,
            "foxglovePanelTitle": "reward terms",
        },
        "StateTransitions!endings": {
            "paths": [
                _series(_path(steps, name), name, plot=False)
                for name in ("episode", "terminated", "truncated")
            ],
            "isSynced": True,
            "foxglovePanelTitle": "episodes and endings",
        },
        "RawMessages!step": {
            "topicPath": _path(steps),
            "diffEnabled": False,
            "diffMethod": "custom",
            "diffTopicPath": "",
            "showFullMessageForDiff": False,
            "foxglovePanelTitle": "step",
        },
        "RosOut!endings": {
            "searchTerms": [],
            "minLogLevel": 1,
            "topicToRender": LOG_TOPIC,
            "foxglovePanelTitle": "endings",
        },
    }
    right: Any = _split("column", "RawMessages!step", "RosOut!endings", 40)
    if image_topic is not None:
        config["Image!camera"] = {
            "imageMode": {"imageTopic": image_topic},
            "foxglovePanelTitle": "camera",
        }
        right = _split("column", "Image!camera", right, 50)
    plots = _split(
        "column", "Plot!reward", _split("column", "Plot!terms", "StateTransitions!endings", 67), 40
    )
    layout = {
        "configById": config,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1},
        "layout": _split("row", plots, right, 65),
    }
    return json.dumps(layout, indent=2) + "\n"


def foxglove_layout_of(path: str | os.PathLike[str], stream: str | None = None) -> str:
    """The layout (:func:`foxglove_layout`) of the Foxglove export ``path``, from what it holds.

    Its ``steps`` topic of ``stream`` (a prefix, ``"/env_1"``, ``"/player_0"``; default: the
    first in sorted order), the reward terms its messages' schema lists and its first camera
    topic, if any. Raises :class:`~episode_audit.errors.ConfigurationError` for a file that is
    not a Foxglove export of episode-audit, or a ``stream`` it does not hold.
    """
    topics, marked = _export_topics(path)
    steps = sorted(t for t, (schema, _) in topics.items() if schema == _STEP_SCHEMA)
    if not steps and marked:
        raise ConfigurationError(
            f"{path}: a Foxglove export of a file with no steps or resets: nothing for a layout "
            "to show"
        )
    if not steps:
        raise ConfigurationError(
            f"{path}: not a Foxglove export of episode-audit (no {_STEP_SCHEMA} topic); make "
            "one with: episode-audit export FILE --to foxglove -o OUT"
        )
    prefixes = [t.removesuffix("/steps") for t in steps]
    if stream is None:
        stream = prefixes[0]
    if stream not in prefixes:
        listed = ", ".join(repr(p) for p in prefixes)
        raise ConfigurationError(f"--stream: {path} has no stream {stream!r}; it has {listed}")
    schema = topics[f"{stream}/steps"][1]
    terms = list(schema.get("properties", {}).get("terms", {}).get("properties", {}))
    cameras = sorted(
        t
        for t, (name, _) in topics.items()
        if name == _IMAGE_SCHEMA and t.startswith(f"{stream}/camera/")
    )
    return foxglove_layout(terms, prefix=stream, image_topic=cameras[0] if cameras else None)


def _export_topics(
    path: str | os.PathLike[str],
) -> tuple[dict[str, tuple[str, dict[str, Any]]], bool]:
    """Each topic of the MCAP file ``path`` (schema name, JSON Schema); whether it is marked.

    The mark of episode-audit's export is its metadata record
    (:data:`~episode_audit.format.names.METADATA_EXPORT`).
    """
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
    except OSError as exc:
        raise ConfigurationError(f"{path}: cannot open: {exc.strerror or exc}") from None
    except (McapError, ValueError, struct.error) as exc:
        raise ConfigurationError(
            f"{path}: not an MCAP file a Foxglove export wrote ({exc})"
        ) from None
    if summary is None:
        raise ConfigurationError(f"{path}: an MCAP file without its summary; export it again")
    out = {}
    for channel in summary.channels.values():
        schema = summary.schemas.get(channel.schema_id)
        content: dict[str, Any] = {}
        if schema is not None and schema.encoding == "jsonschema":
            try:
                content = json.loads(schema.data)
            except ValueError:
                content = {}
        out[channel.topic] = (schema.name if schema is not None else "", content)
    marked = any(index.name == fmt.METADATA_EXPORT for index in summary.metadata_indexes)
    return out, marked


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m episode_audit.export.layout [EXPORT] [--stream PREFIX]``: print a layout."""
    parser = argparse.ArgumentParser(
        prog="python -m episode_audit.export.layout",
        description="Print a Foxglove layout (JSON) for a Foxglove export of episode-audit; "
        "import it in Foxglove with Layouts > Import from file…",
        epilog="e.g. python -m episode_audit.export.layout viewers/run.foxglove.mcap > "
        "run.layout.json",
    )
    parser.add_argument(
        "export",
        nargs="?",
        help="a file written by episode-audit export --to foxglove: the layout shows its "
        "topics, reward terms and camera (default: the reference tasks' terms, no prefix)",
    )
    parser.add_argument(
        "--stream",
        metavar="PREFIX",
        help="the stream to show: /env_N (vector env) or /AGENT (PettingZoo); default: the first",
    )
    args = parser.parse_args(argv)
    try:
        if args.export is None:
            if args.stream is not None:
                parser.error("--stream needs an EXPORT file")
            text = foxglove_layout()
        else:
            text = foxglove_layout_of(args.export, args.stream)
    except EpisodeAuditError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
