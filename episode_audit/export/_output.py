"""One viewer file out: checks before writing, a temporary name while writing, the result.

:func:`staged` checks the output path (not the input, not a special file, not an existing file
unless ``overwrite``), creates its folder if missing, yields a temporary file there (unnamed
where the OS has them, so that even a killed export leaves nothing) and gives it the output's
name only when the export finished, so a failed export leaves nothing that looks complete.
:func:`refuse_evidence` keeps every export off a live recorder's file and off evidence, with
or without ``overwrite``.
:class:`ViewerExport` says what was written; :func:`missing` is the error naming the extra a
viewer library needs, :func:`need_pillow` the same for the camera frames' PNG encoder.
"""

from __future__ import annotations

import os
import shlex
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import ConfigurationError
from ..format.columns import counted
from ..read.liveness import still_written, writer_of
from ..read.opening import evidence_header
from ..read.storage import RemoteFile, Source, as_output
from ..record.lock import output_kind
from ..record.published import Temporary, no_space
from ._values import SMALL, has_frames

if TYPE_CHECKING:
    from ..read import Evidence

__all__ = [
    "ViewerExport",
    "episode_count",
    "local_file",
    "missing",
    "need_pillow",
    "refuse_evidence",
    "sdk_failure",
    "staged",
]


@dataclass
class ViewerExport:
    """What a viewer export (``to="foxglove"`` or ``to="rerun"``) wrote."""

    path: Path
    """The file written."""
    source: Source
    """The evidence file read: a local path or a URL (:class:`~episode_audit.read.RemoteFile`)."""
    viewer: str
    """``"foxglove"`` or ``"rerun"``."""
    episodes: int = 0
    """Episodes written, unstarted ones too."""
    steps: int = 0
    resets: int = 0
    """Reset frames written: each episode's observation from ``reset()``, before its steps."""
    frames: int = 0
    """Camera frames (image observations of steps and resets) written as images."""
    paths: list[str] = field(default_factory=list)
    """Topics (Foxglove) or entity paths (Rerun) written, sorted."""
    left_out: list[str] = field(default_factory=list)
    """Action / observation fields neither plotted nor shown as images (too large, digests,
    text), by name."""
    unfinished: str | None = None
    """Why the input is unfinished (still being written, or torn); ``None``: finished."""
    out_of_range: int = 0
    """Steps, resets and episodes left out: their times are missing or outside what the
    viewer's timestamps hold (1970 to 2106 for Foxglove; only a file not from our recorder has
    such)."""
    unstarted: int = 0
    """Of :attr:`episodes`, those reset and never stepped (``show`` and ``report`` count them
    apart)."""

    @property
    def notes(self) -> list[str]:
        """Lines for people: what of the input is not in the output, and why."""
        lines = []
        if self.unfinished is not None:
            lines.append(f"{self.source} is unfinished ({self.unfinished}): exported what it holds")
        if self.left_out:
            lines.append(
                f"{self.source}: not plotted (more than {SMALL} numbers, digests or text): "
                + ", ".join(self.left_out)
            )
        if self.out_of_range:
            lines.append(
                f"{self.source}: {self.out_of_range} step(s), reset(s) or episode(s) left out: "
                f"their times are missing or outside what {self.viewer.capitalize()} timestamps "
                "hold"
            )
        return lines

    def summary(self) -> str:
        """Lines for people: what was written where, then how to look at it.

        A command to run is a line of its own, indented, whole however long (to copy).
        """
        frames = f", {self.frames} camera frames" if self.frames else ""
        out = shlex.quote(str(self.path))
        if self.viewer == "foxglove" and not any(p.endswith("/steps") for p in self.paths):
            look = "open it in Foxglove (no steps or resets: no layout)"
        elif self.viewer == "foxglove":
            look = (
                "open it in Foxglove; a layout for it:\n"
                f"  python -m episode_audit.export.layout {out} > layout.json"
            )
        else:
            look = f"open it with: rerun {out}"
        counts = f"{episode_count(self.episodes, self.unstarted)}, {counted(self.steps, 'step')}"
        return f"wrote {counts}{frames} of {self.source} to {self.path}\n{look}"


def episode_count(episodes: int, unstarted: int) -> str:
    """``episodes`` (``unstarted`` of them) as ``show`` counts them: the unstarted apart.

    >>> episode_count(3, 0), episode_count(3, 2), episode_count(2, 2)
    ('3 episodes', '1 episode (+2 unstarted)', '0 episodes (+2 unstarted)')
    """
    started = counted(episodes - unstarted, "episode")
    return f"{started} (+{unstarted} unstarted)" if unstarted else started


def missing(
    module: str,
    extra: str,
    *,
    needs: tuple[int, int] | None = None,
    running: Sequence[int] = sys.version_info[:3],
    why: str | None = None,
) -> ConfigurationError:
    """The error for a viewer library that is not installed: it names the extra to install.

    ``needs``: the oldest Python the library has a release for; on an older one (``running``)
    the error says so rather than name an extra that installs nothing there. ``why``: what
    the package is for, when the extra's name does not say it.

    >>> print(missing("rerun-sdk", "rerun", needs=(3, 11), running=(3, 10, 13)))
    --to rerun: needs the 'rerun-sdk' package, which needs Python >= 3.11 (this is Python 3.10.13)
    """
    if needs is not None and tuple(running[:2]) < needs:
        this = ".".join(str(part) for part in running[:3])
        return ConfigurationError(
            f"--to {extra}: needs the {module!r} package, which needs Python >= "
            f"{needs[0]}.{needs[1]} (this is Python {this})"
        )
    what = f"{module!r} package" + (f" ({why})" if why else "")
    return ConfigurationError(
        f"--to {extra}: needs the {what}; install it with pip install 'episode-audit[{extra}]'"
    )


def need_pillow(ev: Evidence, extra: str) -> None:
    """Refuse a file with camera frames when Pillow, their PNG encoder, is not installed.

    Called before anything is written; a file without frames needs no Pillow (both viewer
    extras install it, a viewer library installed on its own does not).
    """
    if not has_frames(ev.steps_schema):
        return
    try:
        import PIL.Image  # noqa: F401 (imported where the frames are written)
    except ImportError:
        raise missing("pillow", extra, why="to write camera frames") from None


def sdk_failure(
    out: Path, library: str, exc: Exception, doing: str = "write", why: str | None = None
) -> ConfigurationError:
    """The one-line error for the viewer ``library``'s own error ``exc`` in writing ``out``.

    A disk with no space left says so (:func:`~episode_audit.record.published.no_space`); any
    other failure as the library says it (or ``why``), after ``{out}: {library} cannot {doing}
    it``.
    """
    said = exc if why is None else why
    return no_space(out, exc) or ConfigurationError(f"{out}: {library} cannot {doing} it: {said}")


def local_file(out: str | os.PathLike[str], viewer: str) -> Path:
    """``out`` as the local file a viewer export writes; a URL is refused (export, then copy).

    What is a URL is :func:`~episode_audit.read.storage.as_output`'s to say.

    >>> local_file("viewers/run.rrd", "rerun")
    PosixPath('viewers/run.rrd')
    """
    target = as_output(out)
    if isinstance(target, RemoteFile):
        raise ConfigurationError(
            f"--to {viewer}: --out must be a local file path, got the URL {os.fspath(out)!r}; "
            "export, then copy"
        )
    return target


def refuse_evidence(path: Path) -> None:
    """Refuse to write over ``path`` if it is a live recorder's file or an evidence file.

    An export replaces (with ``overwrite``) an earlier export or any other file, never evidence
    (MCAP with episode-audit's profile: a finished, torn or recovered file alike), and never a
    file a live recorder holds. Only the header's first bytes are read.
    """
    writer = writer_of(path)
    if writer is not None:
        raise ConfigurationError(
            f"{path}: is {still_written(writer)}; an export never replaces a live recorder's "
            "file — choose another output path"
        )
    if evidence_header(path):
        raise ConfigurationError(
            f"{path}: is an evidence file; an export never replaces evidence — choose another "
            "output path"
        )


@contextmanager
def staged(
    source: Source,
    out: Path,
    *,
    overwrite: bool,
    overwrite_option: str = "overwrite=True",
) -> Iterator[Path]:
    """A file to write ``out`` to, published as ``out`` if the block succeeds.

    Before the block: ``out`` is checked (not the input, not a special file, not an existing
    file unless ``overwrite``: the error says to pass ``overwrite_option``), its folder created
    if missing, and a file made there (:class:`~episode_audit.record.published.Temporary`: an
    unnamed one where the OS has them), so an output that cannot be written is said before the
    export. The path yielded exists, empty.
    """
    kind = output_kind(out)
    if kind is not None:
        raise ConfigurationError(
            f"{out}: is {kind}, not a regular file; --out names the file to write"
        )
    exists = f"exists; pass {overwrite_option} to replace it"
    if out.exists():
        if isinstance(source, Path) and out.resolve() == source.resolve():
            raise ConfigurationError(f"{out}: is the input; --out names a new file to write")
        refuse_evidence(out)
        if not overwrite:
            raise ConfigurationError(f"{out}: {exists}")
    temporary = Temporary(out, exists=exists, suffix=".partial")
    try:
        yield temporary.path
        temporary.publish(overwrite)
    finally:
        temporary.discard()
