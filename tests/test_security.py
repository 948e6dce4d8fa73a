"""The trust model of docs/security.md, one test per rule: an evidence file is data, never code."""

from __future__ import annotations

import ast
import html
import json
import os
import pickle
import re
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pyarrow as pa
import pytest
from typer.testing import CliRunner

from episode_audit import RecordEvidence, check, export, open_evidence, replay, report
from episode_audit.cli import app
from episode_audit.errors import CorruptEvidenceError
from episode_audit.format import names as fmt
from episode_audit.read.episodes import MAX_JSON_BYTES
from tests.support.envs import ScriptedEnv
from tests.support.hostile import HOSTILE, PIECES, replace_column, rewrite

PACKAGE = Path(__file__).resolve().parents[1] / "episode_audit"
runner = CliRunner()


def cli(*args: str) -> tuple[int, str, str]:
    result = runner.invoke(app, list(args))
    if result.exception and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


# ----------------------------------------------------------------------- rule 1: no code from data

_FORBIDDEN_MODULES = {"pickle", "cPickle", "_pickle", "marshal", "shelve", "dill", "cloudpickle"}
_FORBIDDEN_CALLS = {"eval", "exec", "compile", "__import__"}
# import_module calls whose argument is not a constant: the user's --import / --env-factory /
# --policy (command-line arguments and library arguments), never a string read from a file.
_DYNAMIC_IMPORTS_ALLOWED = {("_usercode.py", "_import")}
# The package's own lazy attributes (a fixed table of its own modules), and PettingZoo replay,
# which imports a module named in a file only after is_pettingzoo_module() found it inside the
# installed pettingzoo package (or with --trust-entry-points); tests/record/test_pettingzoo.py
# pins both paths.
_DYNAMIC_IMPORTS_ALLOWED |= {("__init__.py", "__getattr__")}
_DYNAMIC_IMPORTS_ALLOWED |= {("replay/envs.py", "_from_pettingzoo_module")}


def _is_re(func: ast.expr) -> bool:
    """``re.compile(...)``: a regular expression, not code."""
    return (
        isinstance(func, ast.Attribute)
        and isinstance(func.value, ast.Name)
        and func.value.id == "re"
    )


def _enclosing_functions(tree: ast.AST) -> dict[ast.AST, str]:
    owner: dict[ast.AST, str] = {}
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for inner in ast.walk(node):
                owner.setdefault(inner, node.name)
    return owner


def test_the_package_never_unpickles_evals_or_imports_what_it_reads() -> None:
    problems: list[str] = []
    for path in sorted(PACKAGE.rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        owner = _enclosing_functions(tree)
        for node in ast.walk(tree):
            where = f"{path.relative_to(PACKAGE)}:{getattr(node, 'lineno', '?')}"
            if isinstance(node, ast.Import):
                names = {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom):
                names = {(node.module or "").split(".")[0]}
            else:
                names = set()
            if names & _FORBIDDEN_MODULES:
                problems.append(f"{where}: imports {sorted(names & _FORBIDDEN_MODULES)}")
            if not isinstance(node, ast.Call):
                continue
            func = node.func
            name = func.id if isinstance(func, ast.Name) else getattr(func, "attr", "")
            if name in _FORBIDDEN_CALLS and not (name == "compile" and _is_re(func)):
                problems.append(f"{where}: calls {name}()")
            if name in ("load", "loads") and any(
                k.arg == "allow_pickle" for k in node.keywords
            ):  # numpy's np.load(allow_pickle=True)
                problems.append(f"{where}: {name}(allow_pickle=...)")
            if name == "import_module" and not (
                node.args and isinstance(node.args[0], ast.Constant)
            ):
                key = (path.relative_to(PACKAGE).as_posix(), owner.get(node, ""))
                if key not in _DYNAMIC_IMPORTS_ALLOWED:
                    problems.append(f"{where}: import_module of a computed name in {key[1]}()")
    assert problems == [], "\n".join(problems)


class _Touch:
    """Unpickling this creates ``marker``: evidence that something unpickled file content."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, ...]:
        return (Path.touch, (self.marker,))


CANARY = """
from pathlib import Path
Path(__file__).with_name("IMPORTED").touch()
def make(*args, **kwargs):
    raise RuntimeError("canary called")
"""


@pytest.fixture
def canary(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An importable module that leaves a marker file when imported; returns the marker."""
    (tmp_path / "ea_canary_module.py").write_text(CANARY)
    monkeypatch.syspath_prepend(str(tmp_path))
    yield tmp_path / "IMPORTED"
    sys.modules.pop("ea_canary_module", None)


def test_a_file_naming_pickles_and_modules_imports_and_unpickles_nothing(
    tmp_path: Path, canary: Path
) -> None:
    payload = pickle.dumps(_Touch(tmp_path / "UNPICKLED")).hex()
    source = tmp_path / "plain.mcap"
    with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=5), source) as env:
        env.reset(seed=0)
        for _ in range(5):
            env.step(0)

    def run(meta: dict[str, str]) -> dict[str, str]:
        spec = json.loads(meta["env_spec"])
        spec["entry_point"] = "ea_canary_module:make"
        spec["additional_wrappers"] = [
            {"name": "W", "entry_point": "ea_canary_module:make", "kwargs": {}},
            {"name": "V", "entry_point": "gymnasium.wrappers.common:np.load", "kwargs": {}},
        ]
        space = {"type": "Custom", "class": "ea_canary_module.Space", "repr": payload}
        terms = {"source": "callable:ea_canary_module.make", "constants": {}}
        return {
            **meta,
            "env_id": "ea_canary_module:Evil-v0",
            "env_spec": json.dumps(spec),
            "observation_space": json.dumps(space),
            "reward_terms": json.dumps(terms),
            "tags": json.dumps({"pickle": payload}),
            "pickle": payload,
        }

    def steps(batch: pa.RecordBatch) -> pa.RecordBatch:
        i = batch.schema.get_field_index(fmt.COL_INFO)
        pickled = {b"ARROW:extension:name": b"arrow.py_extension_type"}
        pickled[b"ARROW:extension:metadata"] = bytes.fromhex(payload)
        field = batch.schema.field(i).with_metadata(pickled)
        return batch.set_column(i, field, pa.array([payload] * batch.num_rows, pa.string()))

    evil = rewrite(source, tmp_path / "evil.mcap", run=run, steps=steps)
    ev = open_evidence(evil)
    ev.steps()
    check([evil])
    report([evil], by="env")
    export([evil], tmp_path / "out")
    (episode,) = replay([evil]).episodes
    assert episode.status == "not_replayable" and "--trust-entry-points" in (episode.reason or "")
    for fmt_ in ("table", "markdown", "json"):
        assert cli("show", str(evil), "--format", fmt_)[0] == 0
        assert cli("show", str(evil), "--episode", "0", "--format", fmt_)[0] == 0
    assert "ea_canary_module" not in sys.modules
    assert not canary.exists()
    assert not (tmp_path / "UNPICKLED").exists()


# ----------------------------------------------------------------------- rule 2: replay's imports


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """CartPole recorded with ``render_mode="rgb_array"`` (RecordVideo would run in it)."""
    path = tmp_path_factory.mktemp("rendered") / "rendered.mcap"
    env = gym.make("CartPole-v1", max_episode_steps=3, render_mode="rgb_array")
    with RecordEvidence(env, path) as rec:
        rec.reset(seed=0)
        for _ in range(3):
            rec.step(0)
    return path


def _with_wrappers(src: Path, dst: Path, wrappers: list[Any]) -> Path:
    def run(meta: dict[str, str]) -> dict[str, str]:
        spec = json.loads(meta["env_spec"])
        spec["additional_wrappers"] = wrappers
        return {**meta, "env_spec": json.dumps(spec)}

    return rewrite(src, dst, run=run)


def _wrapper(entry: str, **kwargs: Any) -> dict[str, Any]:
    return {"name": entry.rpartition(":")[2], "entry_point": entry, "kwargs": kwargs}


_VIDEO = "gymnasium.wrappers.rendering:RecordVideo"
_WAY_AROUND = (
    "; pass --env-factory MODULE:CALLABLE that builds the env, or --trust-entry-points to build "
    "the recorded wrappers as they are"
)
_REFUSED = [
    (
        [_wrapper("ea_canary_module:make")],
        "the recorded wrapper 'ea_canary_module:make' is not one replay knows",
    ),
    (
        [_wrapper("gymnasium.wrappers.common:np.save", file="x")],
        "the recorded wrapper 'gymnasium.wrappers.common:np.save' is not one replay knows",
    ),
    (
        [_wrapper("gymnasium.wrappers.transform_reward:TransformReward", func="os:system")],
        "the recorded wrapper TransformReward: its argument func is a function, which a file "
        "cannot hold",
    ),
    (
        [_wrapper("gymnasium.wrappers:ClipReward", min_reward="../../x", max_reward=1.0)],
        "the recorded wrapper ClipReward's argument min_reward: expected a finite number or a "
        "list of at most 4096, or null, got '../../x'",
    ),
    (
        [_wrapper("gymnasium.wrappers.common:TimeLimit", max_episode_steps=5, path="/srv/x")],
        "the recorded wrapper TimeLimit has an argument 'path' replay does not know",
    ),
    (
        # (a file without state snapshots: tests/replay/test_state.py restores those)
        [_wrapper("gymnasium.wrappers.stateful_observation:NormalizeObservation", epsilon=1e-8)],
        # (a cause replay reads from the file, whatever env it could build: no way around)
        "the recorded wrapper NormalizeObservation keeps running statistics across episodes, "
        "which the file does not hold (no state snapshot): its episodes cannot begin in the "
        "state they were recorded in; record with the recorder inside NormalizeObservation "
        "(innermost)",
    ),
    (
        [
            _wrapper(
                "gymnasium.wrappers.rendering:AddWhiteNoise", probability_of_noise_per_pixel=0.5
            ),
            _wrapper(_VIDEO, video_folder="videos"),
        ],
        "the recorded wrapper AddWhiteNoise depends on the render() calls the recorded "
        "RecordVideo made in each step, and replay leaves RecordVideo out (it has side effects)",
    ),
]


@pytest.mark.parametrize(("wrappers", "reason"), _REFUSED, ids=range(len(_REFUSED)))
def test_replay_never_builds_a_recorded_wrapper_it_cannot_check(
    rendered: Path,
    tmp_path: Path,
    canary: Path,
    monkeypatch: pytest.MonkeyPatch,
    wrappers: list[Any],
    reason: str,
) -> None:
    """Unknown wrappers, file-chosen callables and arguments, wrappers with state across
    episodes: not replayable, naming the wrapper and the argument; nothing imported or written.

    (The file-named entry point itself: tests/replay/test_replay.py
    ``test_replay_never_imports_a_module_named_in_the_file``, with and without the flag.)
    """
    evil = _with_wrappers(rendered, tmp_path / "evil.mcap", wrappers)
    monkeypatch.chdir(tmp_path)
    before = set(tmp_path.rglob("*"))
    (episode,) = replay([evil]).episodes
    way_around = "" if reason.endswith("(innermost)") else _WAY_AROUND
    assert (episode.status, episode.reason) == ("not_replayable", reason + way_around)
    code, out, _ = cli("replay", str(evil), "--format", "json")
    # nothing verified: exit 1 (a usage error or a crash would be 2)
    assert code == 1 and json.loads(out)["summary"]["not_replayable"] == 1
    assert set(tmp_path.rglob("*")) == before
    assert "ea_canary_module" not in sys.modules and not canary.exists()


def test_replay_leaves_out_wrappers_that_write_files_or_open_windows(
    rendered: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """RecordVideo (a folder, a path-traversal prefix, a trigger on every step), HumanRendering
    and SB3's Monitor never change a step: replay leaves them out and says so."""
    folder = tmp_path / "videos"
    wrappers = [
        _wrapper(_VIDEO, video_folder=str(folder), step_trigger=1, name_prefix="../../x"),
        _wrapper(_VIDEO, video_folder="relative", episode_trigger=None, step_trigger=1),
        _wrapper("gymnasium.wrappers.rendering:HumanRendering"),
        _wrapper("stable_baselines3.common.monitor:Monitor", filename="../../monitor.csv"),
    ]
    evil = _with_wrappers(rendered, tmp_path / "evil.mcap", wrappers)
    monkeypatch.chdir(tmp_path)
    before = set(tmp_path.rglob("*"))
    pygame_before = "pygame" in sys.modules
    result = replay([evil])
    assert [e.status for e in result.episodes] == ["identical"]
    never = "never changes a step"
    assert result.notes == {
        str(evil): [
            f"replayed without the recorded wrapper RecordVideo: it {never}",
            f"replayed without the recorded wrapper RecordVideo: it {never}",
            f"replayed without the recorded wrapper HumanRendering: it {never}",
            f"replayed without the recorded wrapper Monitor: it {never}",
        ]
    }
    code, out, _ = cli("replay", str(evil))
    assert code == 0 and "Replayed without recorded wrappers" in out
    assert set(tmp_path.rglob("*")) == before
    if not pygame_before:
        assert "pygame" not in sys.modules  # (HumanRendering would import it)


# ----------------------------------------------------------------------- rule 3: escaping


def _recording_with(tmp: Path, text: str, name: str) -> Path:
    """A file carrying ``text`` in every place a file carries text: env id, spec, tags, term
    names, failure labels, truncation reasons, error messages, recorder notes and kept info."""

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        if env.np_random_seed == 2:
            raise RuntimeError(text)
        info = {"reward_terms": {text: 1.0}, "failure": text, text: text}
        info["truncation_reason"] = text
        reward = text if env.t == 1 else 1.0
        return (
            np.zeros(2, np.float32),
            reward,
            env.t == 2 and env.np_random_seed == 0,
            (env.t == 2 and env.np_random_seed == 1),
            info,
        )

    source = tmp / f"source-{name}"
    tags = {"policy": text, text: "value"}
    with RecordEvidence(ScriptedEnv(step_fn=step), source, tags=tags, info_keys="all") as env:
        for seed in (0, 1, 2):
            env.reset(seed=seed)
            try:
                for _ in range(2):
                    env.step(0)
            except RuntimeError:
                pass

    def run(meta: dict[str, str]) -> dict[str, str]:
        spec = {"id": text, "entry_point": text, "kwargs": {text: text}}
        return {**meta, "env_id": text, "env_spec": json.dumps(spec), "writer": text}

    return rewrite(source, tmp / name, run=run)


@pytest.fixture(scope="module")
def hostile_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """:data:`HOSTILE` in every place a file carries text."""
    return _recording_with(tmp_path_factory.mktemp("hostile"), HOSTILE, "hostile.mcap")


OUTPUTS = [
    ("show",),
    ("show", "--episode", "0"),
    ("report", "--by", "file"),
    ("report", "--by", "env"),
    ("report", "--by", "tag:policy"),
    ("report", "--by", "label"),
    ("check",),
    ("replay",),
]


def _cells(line: str) -> list[str]:
    """Split a GitHub-flavoured Markdown table row on its unescaped pipes."""
    cells, current, escaped = [], "", False
    for c in line.strip()[1:-1]:
        if escaped:
            current += c
            escaped = False
        elif c == "\\":
            current += c
            escaped = True
        elif c == "|":
            cells.append(current)
            current = ""
        else:
            current += c
    return [*cells, current]


@pytest.mark.parametrize("command", OUTPUTS, ids=" ".join)
def test_strings_from_files_print_literally_in_tables(
    hostile_file: Path, command: tuple[str]
) -> None:
    code, out, err = cli(command[0], str(hostile_file), *command[1:], "--format", "table")
    assert code in (0, 1), err
    assert "\x1b" not in out and "\x07" not in out and "\x1b" not in err
    flat = re.sub(r"\s+", "", out)  # Rich folds long cells over lines
    for piece in PIECES:
        assert re.sub(r"\s+", "", piece) in flat, piece


@pytest.mark.parametrize("command", OUTPUTS, ids=" ".join)
def test_strings_from_files_cannot_break_markdown(hostile_file: Path, command: tuple[str]) -> None:
    code, out, err = cli(command[0], str(hostile_file), *command[1:], "--format", "markdown")
    assert code in (0, 1), err
    assert "\x1b" not in out and "\x07" not in out
    assert "\\x1b[31mz" in out
    prose = re.sub(r"^(`{3,})json\n.*?^\1$", "", out, flags=re.M | re.S)  # minus code blocks
    assert "<b>" not in prose.replace("\\<b\\>", "")  # no raw HTML
    assert "`c`" not in prose.replace("\\`c\\`", "")  # no code span
    header_cells = None
    for line in out.splitlines():
        if not line.startswith("|"):
            header_cells = None
            continue
        if header_cells is None:
            header_cells = len(_cells(line))
        assert len(_cells(line)) == header_cells, line
    assert HOSTILE.split("\n")[0].replace("|", "") not in out  # never unescaped


def test_json_output_round_trips_hostile_strings(hostile_file: Path) -> None:
    code, out, _ = cli("report", str(hostile_file), "--by", "label", "--format", "json")
    assert code == 0 and "\x1b" not in out
    keys = {g["key"] for g in json.loads(out)["groups"]}
    assert HOSTILE in keys  # exact, escaped only by JSON


def test_error_lines_on_stderr_are_escaped(tmp_path: Path) -> None:
    bad = tmp_path / f"{HOSTILE.replace('/', '_').replace(chr(10), '_')}.mcap"
    bad.write_bytes(b"not evidence")
    code, _, err = cli("check", str(bad))
    assert code == 2 and "\x1b" not in err and "\\x1b[31mz" in err
    assert len(err.strip().splitlines()) == 1


# CI injection: what a label, tag or env id could make of a GitHub job summary (GFM autolinks,
# raw HTML) or of a CI log (workflow commands: a line starting with `::` once its leading
# whitespace is trimmed, or holding `##[` anywhere, as the GitHub Actions runner parses them)
INJECTIONS = {
    "url": "https://e.invalid/x?a=1",
    "www": "www.e.invalid",
    "email": "mail@e.invalid",
    "xmpp": "xmpp:user@e.invalid/r",
    "command": "::error file=app.py,line=1::pwned",
    "indented-command": "   ::add-mask::x",
    "colons": ":::warning:::x",
    "v1-command": "##[error]pwned",
    "azure-command": "##vso[task.setvariable variable=x]1",
    "html": "<img src=x onerror=alert(1)>",
    "control": "\x1b[31mred\x07\u202eevil\r\n::error::x",
}
WORD_JOINER = "\u2060"  # what cli/render/common.py puts inside `::`, `##[`, after `@`
_WORKFLOW_COMMAND = re.compile(r"##(\[|vso\[|teamcity\[)", re.IGNORECASE)
_HTML_TAGS = {"p", "h3", "h4", "table", "thead", "tbody", "tr", "th", "td", "pre", "code"}


@pytest.mark.parametrize(
    "text",
    [
        "https://e.invalid",
        "Https://E.invalid/a_b?c=d#e",
        "ftp://e.invalid",
        "(www.e.invalid)",
        "*www.e.invalid*",
        "WwW.e.invalid",
        "a.b+c@e.invalid",
        "mailto:u@e.invalid",
        "xmpp:u@e.invalid/r",
        "<https://e.invalid>",
        "[x](https://e.invalid)",
        "![x](https://e.invalid/i.png)",
        "[x][y] [y]: https://e.invalid",
        "https\\://e.invalid",
    ],
)
def test_markdown_values_never_become_links(text: str) -> None:
    """In a table cell and in a heading, as GitHub renders Markdown (cmark-gfm, autolinks on)."""
    import cmarkgfm
    from cmarkgfm.cmark import Options

    from episode_audit.cli.render import markdown_table, markdown_text

    for markdown in (markdown_table(["value"], [[text]]), f"### {markdown_text(text)}"):
        html = cmarkgfm.github_flavored_markdown_to_html(markdown, options=Options.CMARK_OPT_UNSAFE)
        assert "<a" not in html and "<img" not in html, html


@pytest.fixture(scope="module")
def injected(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A file for each of :data:`INJECTIONS`, carrying it everywhere, named after it too."""
    tmp = tmp_path_factory.mktemp("injected")
    return {
        text: _recording_with(tmp, text, f"{i:02d}-{text.replace('/', '_')}.mcap")
        for i, text in enumerate(INJECTIONS.values())
    }


def _every_output(files: dict[str, Path], kind: str, tmp: Path) -> list[tuple[str, str, str]]:
    """``(what, kind, output)`` of every command in format ``kind`` (``stderr`` for error
    lines): on all ``files`` at once, and on each file (show, recover; record naming it)."""
    outputs: list[tuple[str, str, str]] = []

    def run(what: str, *args: str) -> None:
        code, out, err = cli(*args)
        assert code in (0, 1, 2), (what, err)
        outputs.extend([(what, kind, out), (what, "stderr", err)])

    paths = [str(p) for p in files.values()]
    for command in OUTPUTS:
        if command[0] != "show":
            run(" ".join(command), command[0], *paths, *command[1:], "--format", kind)
    if kind == "junit":  # (reports' JUnit cases are their gates; a group a hostile tag)
        gates = ("--max-failure-rate", "0.1", "--fail-on-incentive-warning", "--format", kind)
        run("report gates", "report", *paths, "--by", "tag:policy", *gates)
    for i, (text, path) in enumerate(files.items()):
        if kind == "junit":  # (only check, replay and report write JUnit)
            break
        for episode in ((), ("--episode", "0"), ("--episode", "2")):
            run(f"show {text!r} {episode}", "show", str(path), *episode, "--format", kind)
        if kind != "table":  # (the commands below have one output format)
            continue
        run(f"recover {text!r}", "recover", str(path), "--out", str(tmp / f"{i}.mcap"))
        named = tmp / f"record-{path.name}"
        run(f"record {text!r}", "record", "CartPole-v1", "--out", str(named), "--tag", f"p={text}")
        run(f"record env {text!r}", "record", text, "--out", str(tmp / "never.mcap"))
        (tmp / f"not-{path.name}").write_bytes(b"not evidence")
    if kind == "table":
        run("export", "export", *paths, "--out", str(tmp / "export"))
        run("check unreadable", "check", *map(str, tmp.glob("not-*")))
    return outputs


def _assert_inert(what: str, kind: str, output: str) -> None:
    """No workflow command, control character, link or raw HTML in ``output``."""
    import cmarkgfm
    from cmarkgfm.cmark import Options

    for line in output.splitlines():
        assert not line.lstrip().startswith("::"), (what, kind, line)
        assert not _WORKFLOW_COMMAND.search(line), (what, kind, line)
    hidden = {c for c in output if not c.isprintable() and c not in ("\n", WORD_JOINER)}
    assert not hidden, (what, kind, hidden)
    assert "\\u2060" not in output, (what, kind)  # (a word joiner escaped twice)
    if kind == "markdown":
        html = cmarkgfm.github_flavored_markdown_to_html(output, options=Options.CMARK_OPT_UNSAFE)
        assert "<a" not in html, (what, html)
        tags = set(re.findall(r"</?([A-Za-z][A-Za-z0-9-]*)", html))
        assert tags <= _HTML_TAGS, (what, tags - _HTML_TAGS, html)
    if kind == "json":
        json.loads(output)
    if kind == "junit":
        import xmlschema

        xmlschema.XMLSchema(Path(__file__).parent / "cli" / "junit-10.xsd").validate(output)


def _strings(data: Any) -> set[str]:
    if isinstance(data, dict):
        return {str(k) for k in data} | {s for v in data.values() for s in _strings(v)}
    if isinstance(data, list):
        return {s for v in data for s in _strings(v)}
    return {data} if isinstance(data, str) else set()


@pytest.mark.parametrize("kind", ["table", "markdown", "json", "junit"])
def test_no_output_can_inject_links_html_or_ci_workflow_commands(
    injected: dict[str, Path], tmp_path: Path, kind: str
) -> None:
    outputs = _every_output(injected, kind, tmp_path)
    runs = len(OUTPUTS) - 1 if kind == "junit" else 5 + 3 * len(injected)
    assert len(outputs) >= 2 * runs
    for what, output_kind, output in outputs:
        _assert_inert(what, output_kind, output)


def test_a_defused_value_still_reads_as_it_was(injected: dict[str, Path]) -> None:
    """The escapes are invisible: the table, the rendered Markdown and the parsed JSON show
    each value itself (in a table, its word joiners are zero cells wide)."""
    import cmarkgfm

    args = ("report", *map(str, injected.values()), "--by", "tag:policy", "--format")
    _, table_out, _ = cli(*args, "table")
    _, markdown_out, _ = cli(*args, "markdown")
    rendered = cmarkgfm.github_flavored_markdown_to_html(markdown_out)
    shown = html.unescape(re.sub(r"<[^>]*>", "", rendered))
    _, json_out, _ = cli(*args, "json")
    keys = _strings(json.loads(json_out))
    for text in INJECTIONS.values():
        assert text in keys
        if text.isprintable():
            flat = re.sub(r"\s+", "", text)
            assert flat in re.sub(r"\s+", "", table_out.replace(WORD_JOINER, "")), text
            assert flat in re.sub(r"\s+", "", shown.replace(WORD_JOINER, "")), text


# ----------------------------------------------------------------------- rule 4: output paths


def test_output_paths_never_come_from_file_content(tmp_path: Path) -> None:
    source = tmp_path / "in" / "run.mcap"
    source.parent.mkdir()
    tags = {"policy": "../../escaped", "../../x": "../../y"}
    with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=3), source, tags=tags) as env:
        env.reset(seed=0)
        for _ in range(3):
            env.step(0)

    def run(meta: dict[str, str]) -> dict[str, str]:
        return {**meta, "env_id": "../../../escaped", "writer": "/srv/escaped"}

    evil = rewrite(source, tmp_path / "in" / "evil.mcap", run=run)
    before = {p for p in tmp_path.rglob("*")}
    out = tmp_path / "deep" / "out"
    code, _, err = cli("export", str(evil), str(source), "--out", str(out))
    assert code == 0, err
    created = {p for p in tmp_path.rglob("*")} - before
    assert {p.relative_to(tmp_path).as_posix() for p in created if p.is_file()} == {
        "deep/out/episodes.parquet",
        "deep/out/evil.steps.parquet",
        "deep/out/run.steps.parquet",
    }
    before = {p for p in tmp_path.rglob("*")}
    code, _, err = cli("recover", str(evil), "-o", str(tmp_path / "deep" / "fixed.mcap"))
    assert code == 0, err
    created = {p for p in tmp_path.rglob("*")} - before
    assert {p.relative_to(tmp_path).as_posix() for p in created} == {"deep/fixed.mcap"}


@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_the_recorder_refuses_a_path_that_is_not_a_regular_file(tmp_path: Path, kind: str) -> None:
    """A FIFO would block the recorder (here it has a reader, so nothing can hang), a device
    swallow the evidence: refused, even with ``overwrite=True``, before anything is written."""
    from episode_audit.errors import ConfigurationError

    path = Path(os.devnull)
    reader = None
    if kind == "fifo":
        path = tmp_path / "pipe.mcap"
        os.mkfifo(path)
        reader = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    env = gym.make("CartPole-v1")
    try:
        what = "a FIFO (named pipe)" if kind == "fifo" else "a character device"
        with pytest.raises(ConfigurationError, match=re.escape(f"{path}: is {what}, not a reg")):
            RecordEvidence(env, path, overwrite=True)
        if reader is not None:
            assert os.read(reader, 1) == b""  # no writer ever opened the pipe
    finally:
        env.close()
        if reader is not None:
            os.close(reader)


# ----------------------------------------------------------------------- rule 5: bounded sizes


@pytest.fixture(scope="module")
def plain(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("plain") / "plain.mcap"
    with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=4), path) as env:
        env.reset(seed=0)
        for _ in range(4):
            env.step(0)
        env.reset()
    return path


def test_a_huge_metadata_value_is_refused(plain: Path, tmp_path: Path) -> None:
    huge = json.dumps({"policy": "x" * MAX_JSON_BYTES})
    evil = rewrite(plain, tmp_path / "huge.mcap", run=lambda m: {**m, "tags": huge})
    with pytest.raises(CorruptEvidenceError, match="run metadata value exceeds the 1 MiB limit"):
        open_evidence(evil)
    code, _, err = cli("report", str(evil))
    assert code == 2 and "exceeds the 1 MiB limit" in err and len(err.splitlines()) == 1


def test_deeply_nested_metadata_is_refused_not_a_recursion_error(
    plain: Path, tmp_path: Path
) -> None:
    deep = "[" * 200_000 + "]" * 200_000
    evil = rewrite(plain, tmp_path / "deep.mcap", run=lambda m: {**m, "command_line": deep})
    with pytest.raises(CorruptEvidenceError, match="'command_line' is nested too deeply"):
        open_evidence(evil)
    code, _, err = cli("show", str(evil))
    assert code == 2 and "nested too deeply" in err


@pytest.mark.parametrize(
    ("notes", "expected"),
    [
        ("[" * 100_000, "notes_unreadable"),
        (json.dumps(["x" * MAX_JSON_BYTES]), "notes_unreadable"),
    ],
    ids=["deep", "huge"],
)
def test_hostile_step_cells_are_bounded_in_check(
    plain: Path, tmp_path: Path, notes: str, expected: str
) -> None:
    def steps(batch: pa.RecordBatch) -> pa.RecordBatch:
        batch = replace_column(batch, fmt.COL_NOTES, [notes] * batch.num_rows)
        return replace_column(batch, fmt.COL_INFO, [notes] * batch.num_rows)

    evil = rewrite(plain, tmp_path / "cells.mcap", steps=steps)
    found = [f for f in check([evil]).findings if f.code == f"recorder_note:{expected}"]
    assert [(f.episode, f.step) for f in found] == [(0, 0)]
    assert len(found[0].message) < 300


def test_hostile_reset_json_is_not_replayable_not_a_crash(tmp_path: Path) -> None:
    deep = "[" * 100_000
    plain = tmp_path / "two.mcap"  # (two episodes stepped: replay lists no unstarted one)
    with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=4), plain) as env:
        for seed in (0, None):
            env.reset(seed=seed)
            for _ in range(4):
                env.step(0)

    def episodes(batch: pa.RecordBatch) -> pa.RecordBatch:
        batch = replace_column(batch, "rng_state", [None, deep][: batch.num_rows])
        return replace_column(batch, "options", [deep, None][: batch.num_rows])

    evil = rewrite(plain, tmp_path / "rng.mcap", episodes=episodes)
    result = replay([evil])
    assert [(e.status, e.reason) for e in result.episodes] == [
        ("not_replayable", "its reset record: options is nested too deeply to be JSON "
         "episode-audit wrote"),
        ("not_replayable", "its reset record: rng_state is nested too deeply to be JSON "
         "episode-audit wrote"),
    ]  # fmt: skip


@pytest.fixture(scope="module")
def lake(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("lake") / "lake.mcap"
    env = gym.make("FrozenLake-v1", desc=["SF", "FG"], is_slippery=False)
    with RecordEvidence(env, path) as rec:
        rec.reset(seed=0)
        rec.step(2)
    return path


def _with_kwargs(src: Path, dst: Path, **kwargs: Any) -> Path:
    def run(meta: dict[str, str]) -> dict[str, str]:
        spec = json.loads(meta["env_spec"])
        spec["kwargs"] = {**spec["kwargs"], **kwargs}
        return {**meta, "env_spec": json.dumps(spec)}

    return rewrite(src, dst, run=run)


@pytest.mark.parametrize(
    ("kwargs", "reason"),
    [
        (
            {"desc": ["S" + "F" * 998 + "G"] * 1000},  # 30 s and 2 GB to build
            "the recorded env kwarg 'desc' is 1004000 bytes of JSON (all: 1004010), more than "
            "the 65536 replay builds an env from",
        ),
        (
            {"map_name": json.loads("[" * 20 + "]" * 20)},
            "the recorded env kwarg 'map_name' is nested 20 deep, more than the 16 replay "
            "builds an env from",
        ),
    ],
    ids=["large", "deep"],
)
def test_recorded_env_kwargs_are_bounded_before_an_env_is_built(
    lake: Path, tmp_path: Path, kwargs: dict[str, Any], reason: str
) -> None:
    evil = _with_kwargs(lake, tmp_path / "evil.mcap", **kwargs)
    (episode,) = replay([evil]).episodes
    way_around = "; pass --env-factory MODULE:CALLABLE that builds the env"
    assert (episode.status, episode.reason) == ("not_replayable", reason + way_around)
    assert replay([lake]).count("identical") == 1  # (the file as recorded)
    small = gym.make("FrozenLake-v1", desc=["SF", "FG"], is_slippery=False)
    assert replay([evil], env_factory=lambda: small).count("identical") == 1
