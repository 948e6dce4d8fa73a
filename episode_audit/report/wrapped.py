"""Whose rewards the returns are: the reward wrappers each file's recorder sat over.

A file recorded over ``NormalizeReward``, ``TransformReward``, ``ClipReward`` or SB3's
``VecNormalize`` holds that wrapper's rewards (``check``'s ``rewards_changed`` note), so the
returns ``report`` and ``compare`` read from it are not the env's. :func:`file_chain` names a
file's wrappers; :class:`Wrapped` counts the files of each chain of them, says so in one line
(:meth:`Wrapped.note`) and as JSON (:meth:`Wrapped.to_json`). :func:`file_setup` adds
the settings each wrapper was recorded with: returns under a ``ClipReward`` to 1 and one to 0.5
are in different units too.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from ..format.wrappers import reward_wrapper_names, reward_wrapper_setups
from ..read import Evidence

__all__ = ["NOTE_WIDTH", "Chain", "Wrapped", "chain_text", "file_chain", "file_setup"]

Chain = tuple[str, ...]
"""The class names of a file's reward wrappers, innermost first (``()``: none)."""

NOTE_WIDTH = 80
"""The most characters :meth:`Wrapped.note` takes: one line of a terminal."""


def file_chain(ev: Evidence) -> Chain:
    """The reward wrappers the recorder of ``ev`` sat over (the run layout's)."""
    return tuple(reward_wrapper_names(ev.run.layout))


def file_setup(ev: Evidence) -> str | None:
    """The reward wrappers of ``ev`` with their recorded settings, as one string (``None``: none).

    Files of the same setup have returns in the same units, as far as the files tell
    (:func:`~episode_audit.format.wrappers.reward_wrapper_setups`: a setting the spec did not
    record is not there to differ).
    """
    return chain_text(tuple(reward_wrapper_setups(ev.run.layout, ev.run.env_spec)))


def chain_text(chain: Chain) -> str | None:
    """A chain as one string, innermost first (``None``: no wrapper).

    >>> chain_text(("NormalizeReward", "ClipReward")), chain_text(())
    ('NormalizeReward+ClipReward', None)
    """
    return "+".join(chain) or None


@dataclass(frozen=True)
class Wrapped:
    """How many of ``files`` files were recorded over each chain of reward wrappers."""

    files: int = 0
    chains: dict[Chain, int] = field(default_factory=dict)
    """Chain to its number of files; files without a reward wrapper are not counted here."""

    @classmethod
    def of(cls, chains: Iterable[Chain]) -> Wrapped:
        """The count of the files whose chains are ``chains`` (one per file)."""
        listed = list(chains)
        counted: dict[Chain, int] = {}
        for chain in listed:
            if chain:
                counted[chain] = counted.get(chain, 0) + 1
        return cls(len(listed), counted)

    @property
    def wrapped(self) -> int:
        """The number of files recorded over a reward wrapper."""
        return sum(self.chains.values())

    def note(self, side: str = "") -> str | None:
        """One line, at most :data:`NOTE_WIDTH` characters, when some returns are a wrapper's.

        ``side`` (``"baseline"``, ``"candidate"``) names whose files. The chains, most files
        first, are cut to fit (JSON has them all: :meth:`to_json`).

        >>> Wrapped(5, {("NormalizeReward",): 3}).note()
        "3/5 files' returns are not the env's: NormalizeReward"
        >>> Wrapped(2, {("NormalizeReward", "TransformReward"): 2}).note("candidate")
        "Candidate 2/2 files' returns are not the env's: NormalizeReward+TransformReward"
        >>> Wrapped(2).note() is None
        True
        """
        if not self.chains:
            return None
        ordered = sorted(self.chains.items(), key=lambda item: (-item[1], item[0]))
        chains = ", ".join(str(chain_text(chain)) for chain, _ in ordered)
        who = f"{side.capitalize()} " if side else ""
        head = f"{who}{self.wrapped}/{self.files} files' returns are not the env's: "
        room = NOTE_WIDTH - len(head)
        if len(chains) > room:
            chains = chains[: max(room - 1, 0)] + "…"
        return head + chains

    def to_json(self) -> list[dict[str, Any]]:
        """Each chain and its number of files, most files first (JSON ``reward_wrappers``)."""
        ordered = sorted(self.chains.items(), key=lambda item: (-item[1], item[0]))
        return [{"wrappers": list(chain), "files": n} for chain, n in ordered]
