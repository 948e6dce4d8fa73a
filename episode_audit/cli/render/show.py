"""What ``episode-audit show`` prints: a file's summary, or one episode's steps.

:func:`summary_output` renders :func:`~episode_audit.read.summary.summarize` (the library view of
a file) and :func:`episode_output` one episode's steps (:func:`episode_rows`), as a table,
Markdown or JSON. Spaces are shown with their shape and dtype:

>>> space_text({"type": "Box", "shape": [11], "dtype": "float64", "low": -1.0, "high": 1.0})
'Box(shape=(11,), dtype=float64)'
>>> space_text({"type": "Discrete", "n": 3, "start": -1, "dtype": "int64"})
'Discrete(n=3, start=-1, shape=(), dtype=int64)'
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pyarrow as pa
from gymnasium import spaces
from gymnasium.spaces import Space
from rich.console import Group, RenderableType
from rich.text import Text

from ...errors import EvidenceError
from ...format import names as fmt
from ...format.columns import counted
from ...format.options import decode_typed
from ...format.records import from_json, to_jsonable
from ...format.run_end import RunEnd
from ...format.spaces import SpaceCodec
from ...format.unrecorded import unrecorded
from ...read import Evidence
from ...read.summary import EPISODE_LIST_HEAD, EPISODE_LIST_TAIL, rebuilt_space, summarize
from .common import OutputFormat, fmt_number, markdown_table, markdown_text, safe, table, to_json

__all__ = ["episode_output", "episode_rows", "space_text", "summary_output"]

_SPACE_TEXT_LIMIT = 300
"""The longest space text (a Dict of many spaces is cut)."""


def _observation_text(description: Any, data: dict[str, Any]) -> str:
    text = space_text(description)
    limit = data.get("observation_digest_min_bytes")
    if limit is None:
        return text
    return (
        f"{text}; arrays of {limit} bytes or more stored as 16-byte BLAKE2b digests "
        "(replay compares them, show and export cannot give their values)"
    )


def space_text(description: Any) -> str:
    """A described space as one line with its shape and dtype (examples: the module docstring).

    Composite spaces show their parts: ``Dict(obs: Box(shape=(3,), dtype=float32), …)``;
    spaces without one shape (``Text``, ``Sequence``, ``Graph``) read as Gymnasium prints them.
    A description that does not parse shows its type only, e.g. ``Box(?)``.
    """
    space = rebuilt_space(description)
    if space is None:
        kind = description.get("type") if isinstance(description, dict) else None
        if kind == "Custom":
            return f"Custom({description.get('class', '?')})"
        return f"{kind}(?)" if isinstance(kind, str) else "?"
    text = _space_text(space)
    if len(text) > _SPACE_TEXT_LIMIT:
        text = text[: _SPACE_TEXT_LIMIT - 3] + "..."
    return text


def _space_text(space: Space[Any]) -> str:
    if isinstance(space, spaces.Dict):
        return f"Dict({', '.join(f'{k}: {_space_text(s)}' for k, s in space.spaces.items())})"
    if isinstance(space, spaces.Tuple):
        return f"Tuple({', '.join(_space_text(s) for s in space.spaces)})"
    if space.shape is None or space.dtype is None:
        return repr(space)
    extra = ""
    if isinstance(space, spaces.Discrete):
        start = int(space.start)
        extra = f"n={int(space.n)}, " + (f"start={start}, " if start else "")
    return f"{type(space).__name__}({extra}shape={space.shape}, dtype={space.dtype})"


def _layout_text(layout: dict[str, Any]) -> str:
    """``single``, or e.g. ``vector: 8 sub-envs (SyncVectorEnv, NextStep)``."""
    kind = str(layout.get("kind", "single"))
    if kind == "single":
        return kind
    n = layout.get("num_envs")
    count = counted(n, "sub-env") if isinstance(n, int) else f"{n if n else '?'} sub-envs"
    parts = [count] if kind == "vector" else []
    if layout.get("agents"):
        parts.append("agents " + ", ".join(str(a) for a in layout["agents"]))
    extra = [str(layout[k]) for k in ("vector_class", "autoreset_mode") if layout.get(k)]
    return f"{kind}: {', '.join(parts)}" + (f" ({', '.join(extra)})" if extra else "")


def _env_kwargs_text(layout: dict[str, Any]) -> str:
    """A PettingZoo file's env kwargs as ``name=value, ...``, or why there are none.

    Values are exact where the file holds them typed (``inf``, a tuple); the text is cut to
    :data:`_SPACE_TEXT_LIMIT`.
    """
    kwargs = layout.get("env_kwargs")
    if kwargs is None:
        return "not recorded: replay builds the env with its defaults"
    if not isinstance(kwargs, dict):
        return "?"
    typed = layout.get("env_kwargs_typed")
    if isinstance(typed, str):
        try:
            exact = decode_typed(typed)
        except ValueError:  # (damaged: the JSON form, placeholders said)
            pass
        else:
            kwargs = exact if isinstance(exact, dict) else kwargs
    parts = []
    with np.printoptions(threshold=8, precision=4):
        for name, value in kwargs.items():
            lost = unrecorded(value)
            text = f"<not recorded: {lost}>" if lost is not None else " ".join(repr(value).split())
            parts.append(f"{name}={text}")
    text = ", ".join(parts) or "-"
    return text if len(text) <= _SPACE_TEXT_LIMIT else text[: _SPACE_TEXT_LIMIT - 3] + "..."


def _episode_table(data: dict[str, Any]) -> tuple[str, list[str], list[list[Any]]]:
    """Title, headers and rows of the summary's episode list (the ``… N more`` row included)."""
    listed: list[dict[str, Any]] = data["episode_list"]
    omitted: int = data["episode_list_omitted"]
    kind = str((data["layout"] or {}).get("kind", "single"))
    extra = (
        ["env_index"] if kind == "vector" else ["agent"] if kind.startswith("pettingzoo") else []
    )
    headers = ["episode", *extra, "outcome", "label / reason", "length", "return"]

    def row(e: dict[str, Any]) -> list[Any]:
        label = e["label"] if e["label"] is not None else "-"
        cells = [e["episode"], *(e[key] for key in extra), e["outcome"], label, e["length"]]
        return [*cells, fmt_number(e["return"])]

    rows = [row(e) for e in listed]
    if not omitted:
        return "Episodes", headers, rows
    more = ["…", *("" for _ in extra), f"{omitted} more", "(--all-episodes)", "", ""]
    rows.insert(EPISODE_LIST_HEAD, more)
    title = (
        f"Episodes (first {EPISODE_LIST_HEAD} and last {EPISODE_LIST_TAIL} of {data['episodes']})"
    )
    return title, headers, rows


def summary_output(
    ev: Evidence, output: OutputFormat, *, all_episodes: bool = False
) -> RenderableType | str:
    """Render :func:`summarize` (``all_episodes``: list every episode, not the first and last)."""
    data = summarize(ev, all_episodes=all_episodes)
    if output == "json":
        return to_json(data)
    status = "finished" if data["finished"] else f"UNFINISHED ({data['torn']})"
    if data["recovered"] is not None:
        status = f"recovered from a torn or damaged file (dropped: {data['recovered']})"
    dropped = RunEnd.of(ev.run_end).lost
    rows = [
        ["file", data["file"]],
        ["status", status],
        *([["dropped", _dropped_text(dropped)]] if dropped else []),
        ["format", data["format_version"]],
        ["writer", data["writer"]],
        ["env id", data["env_id"] or "-"],
        ["layout", _layout_text(data["layout"])],
        *(
            [["env kwargs", _env_kwargs_text(data["layout"] or {})]]
            if str((data["layout"] or {}).get("kind", "")).startswith("pettingzoo")
            else []
        ),
        ["started", data["start_time"]],
        ["tags", ", ".join(f"{k}={v}" for k, v in data["tags"].items()) or "-"],
        ["episodes", data["episodes"]],
        *([["unstarted", _unstarted_text(data["unstarted"])]] if data["unstarted"] else []),
        ["steps", data["steps"]],
        ["outcomes", ", ".join(f"{k} {v}" for k, v in data["outcomes"].items())],
        ["observation space", _observation_text(ev.run.observation_space, data)],
        ["action space", space_text(ev.run.action_space)],
        ["versions", ", ".join(f"{k} {v}" for k, v in data["versions"].items())],
        ["platform", data["platform"]],
        ["command", " ".join(data["command_line"])],
    ]
    title, headers, episode_rows = _episode_table(data)
    if output == "markdown":
        spec = to_json(data["env_spec"]) if data["env_spec"] is not None else "-"
        block = safe_block(spec)
        fence = "`" * max(3, _longest_backtick_run(block) + 1)
        episodes = (
            f"\n\n{title}:\n\n" + markdown_table(headers, episode_rows) if episode_rows else ""
        )
        return (
            markdown_table(["field", "value"], rows)
            + episodes
            + f"\n\nEnv spec:\n\n{fence}json\n{block}\n{fence}\n"
        )
    parts: list[RenderableType] = [table("Evidence file", ["field", "value"], rows)]
    if episode_rows:
        parts.append(table(title, headers, episode_rows))
    if data["env_spec"] is None:
        parts.append(Text("env spec: -"))
    else:  # (the spec whole, to copy: --format json)
        parts.append(table("Env spec", ["key", "value (JSON)"], _spec_rows(data["env_spec"])))
    return Group(*parts)


def _spec_rows(spec: dict[str, Any]) -> list[list[str]]:
    """The env spec's keys, each with its value as one line of JSON.

    >>> _spec_rows({"id": "CartPole-v1", "kwargs": {}, "max_episode_steps": None})
    [['id', '"CartPole-v1"'], ['kwargs', '{}'], ['max_episode_steps', 'null']]
    """
    return [[key, json.dumps(to_jsonable(value), allow_nan=False)] for key, value in spec.items()]


def _unstarted_text(count: int) -> str:
    """The ``unstarted`` row: the episodes reset and never stepped, which no count holds."""
    return f"{count} (reset and never stepped: not counted, as in report)"


def _dropped_text(dropped: str) -> str:
    """The ``dropped`` row: what the recorder could not write (``RunEnd.lost``)."""
    return (
        f"{dropped} the recorder could not write (episode-audit check says why): the file "
        "is not the whole run"
    )


def safe_block(text: str) -> str:
    """Lines of text made :func:`safe` one by one (the lines kept, e.g. of a code block)."""
    return "\n".join(safe(line) for line in text.splitlines())


def _longest_backtick_run(text: str) -> int:
    longest = run = 0
    for c in text:
        run = run + 1 if c == "`" else 0
        longest = max(longest, run)
    return longest


def _cell(value: Any) -> str:
    if value is None:
        return "-"
    if isinstance(value, (tuple, dict, np.ndarray)):  # (Tuple and Dict actions: item by item)
        text = _value_text(value)
        return text if len(text) <= 60 else text[:57] + "..."
    if isinstance(value, float):
        return fmt_number(value, 6)
    if isinstance(value, bytes):
        return value.hex()[:16] + "…"
    text = str(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _value_text(value: Any) -> str:
    """A space's value in a cell: arrays as numpy prints them, Tuple and Dict items by item.

    >>> _value_text((2, np.array([0.078, -0.485], np.float32)))
    '(2, [ 0.078 -0.485])'
    >>> _value_text({"mode": np.int64(1), "pos": np.zeros(2)})
    '{mode: 1, pos: [0. 0.]}'
    """
    if isinstance(value, np.ndarray):
        return np.array2string(value, precision=4, threshold=8, max_line_width=60)
    if isinstance(value, tuple):
        return "(" + ", ".join(_value_text(v) for v in value) + ")"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_value_text(v)}" for k, v in value.items()) + "}"
    if isinstance(value, np.generic):
        return str(value.item())
    return str(value)


def _actions(codec: SpaceCodec | None, column: pa.Array) -> list[Any]:
    """The actions as the space's values; as stored when they do not decode.

    A file not from our recorder may hold values its space cannot rebuild (its own
    ``from_jsonable`` may raise anything): shown as they are rather than not at all.
    """
    if codec is not None:
        try:
            return codec.decode(column)
        except Exception:  # (a display: the stored values, whatever failed)
            pass
    return column.to_pylist()  # type: ignore[no-any-return]


def episode_rows(
    ev: Evidence, index: int, start: int | None, stop: int | None, *, plain: bool = False
) -> tuple[list[str], list[list[Any]], dict[str, Any]]:
    """Headers, rows (step, action, reward, each term, flags, outcome/label, notes), record.

    Cells are display text; with ``plain``, the values themselves (JSON-able: numbers, the
    action as a list, a term absent from a step as ``None``, notes as a list).
    """
    cell = _plain if plain else _cell
    episode = ev.episode(index)
    steps = episode.steps
    n = steps.num_rows
    lo, hi, _ = slice(start, stop).indices(n)
    if n and lo >= hi:
        raise EvidenceError(
            ev.path, f"--steps {start}:{stop} selects no step of episode {index} ({n} steps)"
        )
    part = steps.slice(lo, max(hi - lo, 0))
    codec = ev.action_codec
    action_col = part.column(fmt.COL_ACTION).combine_chunks() if part.num_rows else pa.array([])
    actions = _actions(codec, action_col) if part.num_rows else []
    terms = [dict(t) if t is not None else {} for t in part.column(fmt.COL_TERMS).to_pylist()]
    names = sorted({k for t in terms for k in t})
    headers = ["step", "action", "reward", *names, "terminated", "truncated", "outcome", "notes"]
    rows: list[list[Any]] = []
    records = part.select(
        [
            fmt.COL_STEP,
            fmt.COL_REWARD,
            fmt.COL_TERMINATED,
            fmt.COL_TRUNCATED,
            fmt.COL_OUTCOME,
            fmt.COL_LABEL,
            fmt.COL_NOTES,
        ]
    ).to_pylist()
    for row, action, term in zip(records, actions, terms, strict=True):
        outcome = row[fmt.COL_OUTCOME]
        if outcome and row[fmt.COL_LABEL]:
            outcome = f"{outcome} ({row[fmt.COL_LABEL]})"
        notes = row[fmt.COL_NOTES]
        rows.append(
            [
                row[fmt.COL_STEP],
                cell(action),
                cell(row[fmt.COL_REWARD]),
                *(cell(term.get(name)) for name in names),
                row[fmt.COL_TERMINATED],
                row[fmt.COL_TRUNCATED],
                outcome or ("" if not plain else None),
                (from_json(notes, "notes") if plain else _cell(notes))
                if notes
                else ("" if not plain else []),
            ]
        )
    return headers, rows, episode.record


def _plain(value: Any) -> Any:
    if isinstance(value, bytes):
        return value.hex()
    return to_jsonable(value)


def episode_output(
    ev: Evidence, index: int, start: int | None, stop: int | None, output: OutputFormat
) -> RenderableType | str:
    """Render one episode's steps (optionally a slice of them)."""
    headers, rows, record = episode_rows(ev, index, start, stop, plain=output == "json")
    outcome = record["outcome"]
    label = record.get("failure_label") or record.get("truncation_reason")
    if outcome == "error" and record.get("error_type"):
        label = f"{record['error_type']} in {record.get('error_during') or 'step'}"
    whose = (
        f" (agent {record['agent']})"
        if record.get("agent")
        else f" (sub-env {record['env_index']})"
        if ev.run.layout.get("kind") == "vector" and record.get("env_index") is not None
        else ""
    )
    title = (
        f"episode {index}{whose}: {outcome}{f' ({label})' if label else ''}, "
        f"{record['length']} steps, "
        f"return {fmt_number(record['return'])}, "
        f"seed {record['seed'] if record['seed'] is not None else '-'}"
    )
    if output == "json":
        record = {**record, "term_totals": dict(record.get("term_totals") or [])}
        return to_json({"episode": record, "columns": headers, "rows": rows})
    if output == "markdown":
        return f"### {markdown_text(title)}\n\n" + markdown_table(headers, rows) + "\n"
    return table(title, headers, rows)
