"""``make demo``: the main job on the built-in reference tasks, through the real CLI.

Records each reference MuJoCo task with the competent (``scripted``) and the reward-hacking
(``hacker``) policy under the misaligned ``proxy_reward=True``, then runs ``check``, ``replay``
and ``report`` on the files — the report shows success, failure and truncation side by side,
and flags the hacker, whose high return comes with failed tasks. Files go to ``demo-out/``.

Run it with ``python -m episode_audit.demo [OUT_DIR]``.
"""

from __future__ import annotations

import argparse
import shlex
import shutil
import sys
import time
from pathlib import Path

from .cli import app
from .tasks import TASK_IDS

__all__ = ["main"]

EPISODES = 10


def run(*args: str) -> int:
    """Run one ``episode-audit`` command in-process, echoing it; return its exit code."""
    print(f"\n$ episode-audit {shlex.join(args)}", flush=True)
    try:
        code = app(list(args), prog_name="episode-audit", standalone_mode=False)
    except SystemExit as exc:  # usage errors still exit the standard way
        return int(exc.code or 0)
    return int(code or 0)


MARK = ".episode-audit-demo"
"""The file that marks a folder as the demo's own: the only folders a new run deletes."""


def fresh(folder: Path) -> str | None:
    """Empty ``folder`` for a run (created when missing); why not, when it is not the demo's.

    A folder the demo made (it holds :data:`MARK`) is deleted and made again; an empty one is
    used; any other is left as it is.
    """
    if folder.exists():
        if not folder.is_dir():
            return f"{folder} is not a folder"
        if (folder / MARK).is_file() or _made_before(folder):
            shutil.rmtree(folder)
        elif any(folder.iterdir()):
            return f"{folder} holds files the demo did not make: give a new or empty folder"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / MARK).write_text("made by python -m episode_audit.demo; a new run deletes it\n")
    return None


_MADE = ("*-scripted.mcap", "*-hacker.mcap", "*.foxglove.mcap", "report.html")


def _made_before(folder: Path) -> bool:
    """Whether ``folder`` holds only what a demo run makes (one from before :data:`MARK`)."""
    entries = list(folder.iterdir())
    return bool(entries) and all(
        entry.is_file() and any(entry.match(pattern) for pattern in _MADE) for entry in entries
    )


def main(argv: list[str] | None = None) -> int:
    """Run the demo; returns 0 when every step behaved as the demo expects (2: a bad folder)."""
    parser = argparse.ArgumentParser(
        prog="python -m episode_audit.demo",
        description=(
            "Record the reference MuJoCo tasks with a competent and a reward-hacking policy, "
            "then check, replay, report and export the files, through the real CLI."
        ),
    )
    parser.add_argument(
        "out",
        nargs="?",
        default="demo-out",
        metavar="OUT_DIR",
        help="the folder for the evidence files (default: demo-out; OUT_DIR-viewers too)",
    )
    out = Path(parser.parse_args(sys.argv[1:] if argv is None else argv).out)
    viewers = out.parent / f"{out.name}-viewers"
    for folder in (out, viewers):
        why = fresh(folder)
        if why is not None:
            print(f"episode-audit demo: {why}", file=sys.stderr)
            return 2
    started = time.perf_counter()
    problems: list[str] = []
    for task in TASK_IDS:
        name = task.split("/")[-1].removesuffix("-v0").lower()
        for policy in ("scripted", "hacker"):
            code = run(
                "record", task, "--policy", policy, "--episodes", str(EPISODES), "--seed", "100",
                "--env-kwargs", '{"proxy_reward": true}', "--tag", "reward=proxy",
                "--out", str(out / f"{name}-{policy}.mcap"),
            )  # fmt: skip
            if code:
                problems.append(f"record {task} {policy} exited {code}")
    if run("check", str(out)) != 0:
        problems.append("check found errors")
    if run("replay", str(out)) != 0:
        problems.append("replay diverged")
    html = out / "report.html"
    run("report", str(out), "--by", "tag:policy", "--html", str(html))
    print("\nThe same report as a CI gate: it must fail (exit 1) because of the hacker run.")
    gate = run(
        "report", str(out), "--by", "tag:policy", "--min-success-rate", "0.7",
        "--fail-on-incentive-warning", "--format", "markdown",
    )  # fmt: skip
    print(f"\n(exit code {gate})")
    if gate != 1:
        problems.append(f"the gate should have failed with exit 1, got {gate}")
    # viewer files go beside the evidence directory, not in it: commands given the directory
    # would take an exported MCAP for evidence
    hacker = sorted(out.glob("*-hacker.mcap"))[0]
    foxglove = viewers / hacker.name.replace(".mcap", ".foxglove.mcap")
    layout = foxglove.with_name(hacker.name.replace(".mcap", ".layout.json"))
    if run("export", str(hacker), "--to", "foxglove", "-o", str(foxglove)) != 0:
        problems.append("the Foxglove export failed")
    else:  # its layout: its topics, the task's reward terms
        from .export.layout import foxglove_layout_of

        command = shlex.join(["python", "-m", "episode_audit.export.layout", str(foxglove)])
        print(f"\n$ {command} > {shlex.quote(str(layout))}", flush=True)
        layout.write_text(foxglove_layout_of(foxglove))
    elapsed = time.perf_counter() - started
    if problems:
        print(f"\ndemo: {len(problems)} problem(s): " + "; ".join(problems), file=sys.stderr)
        return 1
    print(f"\ndemo finished in {elapsed:.1f} s; evidence files are in {out}/")
    print(f"HTML report: {html} (open it in a browser; it needs no network)")
    print(
        f"Foxglove file: {foxglove} (open it in Foxglove; its layout: {layout}, with "
        "Layouts > Import from file…)"
    )
    print(
        "Run the commands above yourself with .venv/bin/episode-audit "
        "(or `source .venv/bin/activate` first)."
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
