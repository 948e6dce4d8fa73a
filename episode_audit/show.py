"""What ``episode-audit show`` prints: a file's summary, or one episode's steps.

:func:`summarize` returns the summary as plain data (the library view); :func:`summary_output`
and :func:`episode_output` render it as a table, Markdown or JSON.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np
import pyarrow as pa
from rich.console import Group, RenderableType
from rich.text import Text

from . import format as fmt
from .errors import EvidenceError
from .reader import Evidence
from .records import from_json, to_jsonable
from .render import OutputFormat, fmt_number, markdown_table, markdown_text, safe, table, to_json

__all__ = ["episode_output", "episode_rows", "summarize", "summary_output"]


def summarize(ev: Evidence) -> dict[str, Any]:
    """The file summary: run metadata, versions, env spec, episodes by outcome, finished or not."""
    episodes = ev.episodes()
    outcomes = Counter(episodes.column("outcome").to_pylist())
    run = ev.run
    return {
        "file": str(ev.path),
        "finished": ev.finished,
        "torn": ev.torn,
        "recovered": (ev.run_end or {}).get("dropped", "not recorded")
        if (ev.run_end or {}).get("status") == fmt.RUN_STATUS_RECOVERED
        else None,
        "format_version": run.format_version,
        "writer": run.writer,
        "env_id": run.env_id,
        "start_time": run.start_time,
        "tags": run.tags,
        "episodes": episodes.num_rows,
        "steps": int(sum(episodes.column("length").to_pylist())),
        "outcomes": {k: outcomes.get(k, 0) for k in fmt.OUTCOMES},
        "observation_space": run.observation_space.get("type"),
        "action_space": run.action_space.get("type"),
        "reward_terms": run.reward_terms,
        "versions": run.versions,
        "platform": run.platform,
        "command_line": run.command_line,
        "env_spec": run.env_spec,
        "layout": run.layout,
    }


def _layout_text(layout: dict[str, Any]) -> str:
    """``single``, or e.g. ``vector: 8 sub-envs (SyncVectorEnv, NextStep)``."""
    kind = str(layout.get("kind", "single"))
    if kind == "single":
        return kind
    parts = [f"{layout.get('num_envs', '?')} sub-envs"] if kind == "vector" else []
    if layout.get("agents"):
        parts.append("agents " + ", ".join(str(a) for a in layout["agents"]))
    extra = [str(layout[k]) for k in ("vector_class", "autoreset_mode") if layout.get(k)]
    return f"{kind}: {', '.join(parts)}" + (f" ({', '.join(extra)})" if extra else "")


def summary_output(ev: Evidence, output: OutputFormat) -> RenderableType | str:
    """Render :func:`summarize`."""
    data = summarize(ev)
    if output == "json":
        return to_json(data)
    status = "finished" if data["finished"] else f"UNFINISHED ({data['torn']})"
    if data["recovered"] is not None:
        status = f"recovered from a torn or damaged file (dropped: {data['recovered']})"
    rows = [
        ["file", data["file"]],
        ["status", status],
        ["format", data["format_version"]],
        ["writer", data["writer"]],
        ["env id", data["env_id"] or "-"],
        ["layout", _layout_text(data["layout"])],
        ["started", data["start_time"]],
        ["tags", ", ".join(f"{k}={v}" for k, v in data["tags"].items()) or "-"],
        ["episodes", data["episodes"]],
        ["steps", data["steps"]],
        ["outcomes", ", ".join(f"{k} {v}" for k, v in data["outcomes"].items())],
        ["spaces", f"observation {data['observation_space']}, action {data['action_space']}"],
        ["versions", ", ".join(f"{k} {v}" for k, v in data["versions"].items())],
        ["platform", data["platform"]],
        ["command", " ".join(data["command_line"])],
    ]
    spec = to_json(data["env_spec"]) if data["env_spec"] is not None else "-"
    if output == "markdown":
        block = safe_block(spec)
        fence = "`" * max(3, _longest_backtick_run(block) + 1)
        return (
            markdown_table(["field", "value"], rows)
            + f"\n\nEnv spec:\n\n{fence}json\n{block}\n{fence}\n"
        )
    return Group(table("Evidence file", ["field", "value"], rows), Text("env spec: " + spec))


def safe_block(text: str) -> str:
    """Text for a fenced code block: control characters escaped line by line."""
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
    if isinstance(value, np.ndarray):
        return np.array2string(value, precision=4, threshold=8, max_line_width=60)
    if isinstance(value, float):
        return fmt_number(value, 6)
    if isinstance(value, bytes):
        return value.hex()[:16] + "…"
    text = str(value)
    return text if len(text) <= 60 else text[:57] + "..."


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
    actions = (
        codec.decode(action_col) if codec is not None and part.num_rows else action_col.to_pylist()
    )
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
    title = (
        f"episode {index}: {outcome}{f' ({label})' if label else ''}, {record['length']} steps, "
        f"return {fmt_number(record['return'])}, "
        f"seed {record['seed'] if record['seed'] is not None else '-'}"
    )
    if output == "json":
        record = {**record, "term_totals": dict(record.get("term_totals") or [])}
        return to_json({"episode": record, "columns": headers, "rows": rows})
    if output == "markdown":
        return f"### {markdown_text(title)}\n\n" + markdown_table(headers, rows) + "\n"
    return table(title, headers, rows)
