"""What a replay says: each episode's status and, where it diverged, its first difference.

:class:`Divergence` (where and how an episode first differed, shown in one line),
:class:`EpisodeReplay` (one episode's replay), :class:`ReplayResult` (many, with the library
versions that differ from the recording and the inputs that could not be read), :data:`Status`;
:func:`short` and :func:`env_error` word values and errors as every replay shows them.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Literal

import numpy as np

from ..format.columns import error_message
from ..format.spaces import equal_elements
from ..read.inputs import Unreadable

__all__ = [
    "RESET_RAISED",
    "Divergence",
    "EpisodeReplay",
    "ReplayResult",
    "Status",
    "env_error",
    "none_replayable",
    "not_told_from_cast",
    "not_told_from_history",
    "not_told_from_versions",
    "not_told_unverified",
    "options_not_held",
    "restored_state",
    "short",
]

Status = Literal["identical", "diverged", "not_replayable"]

RESET_RAISED = "its reset raised (an error episode): there is no reset to compare"
"""Why an episode (or a PettingZoo game) whose recorded ``reset()`` raised is not replayable."""


@dataclass(frozen=True)
class Divergence:
    """Where a replay first differed from the evidence (``step`` is ``None`` for the reset)."""

    step: int | None
    field: str
    expected: str
    got: str
    max_abs_diff: float | None = None
    first_difference: str | None = None
    """For an array observation too long to show whole (``expected`` and ``got`` are cut to
    80 characters): the index of the first element that differs, both values and how many
    elements differ."""

    def describe(self) -> str:
        """One line: step, field, expected, got, max abs difference, first difference."""
        where = "reset" if self.step is None else f"step {self.step}"
        notes = []
        if self.max_abs_diff is not None:
            notes.append(f"max abs diff {self.max_abs_diff:.3g}")
        if self.first_difference is not None:
            notes.append(f"first at {self.first_difference}")
        more = f" ({'; '.join(notes)})" if notes else ""
        return f"{where}: {self.field} expected {self.expected}, got {self.got}{more}"

    @classmethod
    def of_observation(
        cls,
        step: int | None,
        expected: Any,
        got: Any,
        max_abs_diff: float | None,
        atol: float,
    ) -> Divergence:
        """An observation that differs (``step`` ``None``: the reset observation).

        When either value is too long to show whole, the first differing element is named.
        ``max_abs_diff`` is the codec's, infinite where a part that is not a number differs
        (text, JSON): of a Dict, Tuple or text observation it is then the numeric parts'
        largest difference, or ``None`` when none of them differs.
        """
        shown = short(expected), short(got)
        cut = any("..." in text for text in shown)
        if max_abs_diff is not None and np.isinf(max_abs_diff):
            kinds = (Mapping, tuple, str, bytes)  # (bytes: a digest, shown in hex)
            if any(isinstance(expected, k) and isinstance(got, k) for k in kinds):
                max_abs_diff = _numeric_difference(expected, got, atol)
        return cls(
            step,
            "observation" if step is not None else "reset_observation",
            *shown,
            max_abs_diff,
            _first_difference(expected, got, atol) if cut else None,
        )


@dataclass(frozen=True)
class EpisodeReplay:
    """The replay of one episode."""

    file: str
    episode: int
    status: Status
    steps: int
    divergence: Divergence | None = None
    reason: str | None = None
    restored: str | None = None
    """For an episode that differed: the state replay restored before its reset, e.g.
    ``"seed 7; 2 earlier episodes in this env"`` (:func:`restored_state`)."""
    unverified: str | None = None
    """For an episode ``not_replayable`` because it differed in an env whose match with the
    recording could not be verified: why not (:func:`not_told_unverified`); its difference
    is kept in :attr:`divergence`."""


@dataclass
class ReplayResult:
    """Replays of many episodes, with the library versions that differ from the recording.

    ``unreadable``: the inputs that could not be read (``replay(..., keep_going=True)``);
    ``missing``: the selected episode indices that no file replayed had; ``notes``: by file,
    what its env was replayed without (recorded wrappers that never change a step, and why);
    ``live``: the files a live recorder is still writing, and by whom (their flushed steps were
    replayed); ``unstarted``: how many episodes were reset and never stepped (no episode to
    verify, as ``check`` and ``report`` count them): not in :attr:`episodes` (their resets were
    replayed, in order; one whose reset differed is listed).
    """

    episodes: list[EpisodeReplay] = field(default_factory=list)
    version_differences: dict[str, dict[str, tuple[str, str]]] = field(default_factory=dict)
    unreadable: list[Unreadable] = field(default_factory=list)
    missing: list[int] = field(default_factory=list)
    notes: dict[str, list[str]] = field(default_factory=dict)
    live: list[tuple[str, str]] = field(default_factory=list)
    unstarted: int = 0

    def count(self, status: Status) -> int:
        """How many episodes ended with ``status``."""
        return sum(1 for e in self.episodes if e.status == status)

    @property
    def verified(self) -> int:
        """How many episodes were actually replayed and compared: identical or diverged.

        0 when every episode was ``not_replayable`` (or there was none): then nothing confirms
        the evidence, and :attr:`ok` is false.
        """
        return sum(1 for e in self.episodes if e.status != "not_replayable")

    @property
    def ok(self) -> bool:
        """True when the replay confirms the evidence, as the command's exit 0 does.

        No episode diverged, at least one was replayed and compared (:attr:`verified`; the
        others may be ``not_replayable``), every selected episode was found (:attr:`missing`)
        and every file read (:attr:`unreadable`). An ``assert replay(files).ok`` then fails on
        an empty list of files, or on files no episode of which could be replayed.
        """
        return (
            self.count("diverged") == 0
            and self.verified > 0
            and not self.missing
            and not self.unreadable
        )

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able form: ``{"summary", "episodes", "version_differences", "notes", "live"}``."""
        return {
            "summary": {
                "verified": self.verified,
                "identical": self.count("identical"),
                "diverged": self.count("diverged"),
                "not_replayable": self.count("not_replayable"),
                "unstarted": self.unstarted,
            },
            "episodes": [asdict(e) for e in self.episodes],
            "version_differences": {
                file: {lib: {"recorded": a, "current": b} for lib, (a, b) in diffs.items()}
                for file, diffs in self.version_differences.items()
            },
            "notes": {file: list(notes) for file, notes in self.notes.items()},
            "live": [{"file": file, "why": why} for file, why in self.live],
        }


def restored_state(
    record: Mapping[str, Any],
    earlier: int,
    *,
    env: str = "this env",
    snapshots: Iterable[str] = (),
    unit: str = "episode",
) -> str:
    """What replay restored before an episode's reset, in one line.

    ``record`` is its episode record (its ``seed``, else its ``rng_state``: an unseeded reset);
    ``earlier`` how many episodes (``unit``: a PettingZoo file's are games) ``env`` (a vector
    file: the sub-env's own) replayed before it; ``snapshots`` names each state snapshot set
    before the reset (e.g. ``"snapshot of NormalizeObservation"``).

    >>> restored_state({"seed": 7}, 0)
    'seed 7; first episode in this env'
    >>> restored_state({"seed": None, "rng_state": "{}"}, 2, env="sub-env 1's env")
    "the recorded RNG state (an unseeded reset); sub-env 1's env after 2 earlier episodes"
    >>> restored_state({"seed": 3}, 1, unit="game")
    'seed 3; this env after 1 earlier game'
    """
    seed = record.get("seed")
    parts = [f"seed {seed}" if seed is not None else "the recorded RNG state (an unseeded reset)"]
    parts.extend(snapshots)
    if earlier:
        parts.append(f"{env} after {earlier} earlier {unit}{'s' if earlier != 1 else ''}")
    else:
        parts.append(f"first {unit} in {env}")
    return "; ".join(parts)


def options_not_held(note: str) -> str:
    """Why an episode (a game) reset with options the file does not hold is not replayable.

    ``note``: the recorder's ``options_unserializable`` note, what the options were.

    >>> print(options_not_held("{'f': <function f>} (JSON has no function values; ...)"))
    its reset options are not in the file ({'f': <function f>} (JSON has no function values; \
...)): replay cannot reset it as recorded; give reset() options of the types a file holds \
(None, bools, ints, floats, text, lists, tuples, dicts, numpy arrays and scalars)
    """
    fix = next((fix for said, fix in _OPTIONS_FIXES if said in note), _TYPES_FIX)
    return (
        f"its reset options are not in the file ({note}): replay cannot reset it as recorded; {fix}"
    )


_TYPES_FIX = (
    "give reset() options of the types a file holds (None, bools, ints, floats, text, lists, "
    "tuples, dicts, numpy arrays and scalars)"
)
_OPTIONS_FIXES = (
    ("changed its options during reset()", "give each sub-env options of its own, or copy them"),
    ("a reader parses", "give reset() smaller options"),
    ("at two places in them", "give reset() each list, dict or array once (a copy)"),
)
"""What to do about options a file does not hold, by what the recorder's note says."""


def none_replayable(
    file: str, records: Iterable[Mapping[str, Any]], reason: str
) -> list[EpisodeReplay]:
    """Every episode of ``records`` not replayable, for one ``reason`` (nothing was stepped)."""
    return [
        EpisodeReplay(file, int(r["episode"]), "not_replayable", 0, reason=reason) for r in records
    ]


def not_told_from_versions(
    episodes: Iterable[EpisodeReplay], versions: Mapping[str, tuple[str, str]]
) -> list[EpisodeReplay]:
    """``episodes`` with each diverged one ``not_replayable``: replayed with other ``versions``.

    ``versions``: the libraries that can change what an env returns whose version differs from
    the recording, ``{library: (recorded, here)}``. A difference replayed so cannot be told from
    the versions' own (a physics library's last bits, say): the tool cannot justify
    ``diverged``. The episode keeps its first difference; its reason names the libraries (the
    result's ``version_differences`` their versions).

    >>> d = EpisodeReplay("f", 0, "diverged", 3, Divergence(2, "reward", "1.0", "1.5"))
    >>> [e.status for e in not_told_from_versions([d], {})]
    ['diverged']
    >>> print(not_told_from_versions([d], {"mujoco": ("3.2.0", "3.1.6")})[0].reason)
    differed at step 2 (reward) with other versions of mujoco than recorded: a difference cannot \
be told from theirs; replay where they match to verify, or allow for them with --atol
    >>> noted = replace(d, reason="state restored: NormalizeObservation snapshot")
    >>> not_told_from_versions([noted], {"numpy": ("2.4.6", "2.2.6")})[0].reason[-54:]
    '--atol (state restored: NormalizeObservation snapshot)'
    """
    if not versions:
        return list(episodes)
    changed = ", ".join(versions)
    out = []
    for e in episodes:
        if e.status == "diverged":
            reason = (
                f"differed{_where(e.divergence)} with other versions of {changed} than recorded: "
                "a difference cannot be told from theirs; replay where they match to verify, or "
                "allow for them with --atol"
            )
            note = "" if e.reason is None else f" ({e.reason})"  # (a diverged one's note)
            e = replace(e, status="not_replayable", reason=reason + note)
        out.append(e)
    return out


def not_told_from_cast(result: EpisodeReplay, first: int, note: str) -> EpisodeReplay:
    """A diverged ``result`` ``not_replayable``: the recorder cast its actions (a step ``first``).

    The env stepped the policy's actions (float64, say); the file holds them cast to the
    space's dtype (``note``, the recorder's ``action_cast``), which is what replay steps. From
    the first cast step on, a difference is the rounding's, no verdict on the env.

    >>> d = EpisodeReplay("f", 0, "diverged", 9, Divergence(3, "observation", "1", "1.01"))
    >>> print(not_told_from_cast(d, 0, "dtype float64 cast to float32").reason)
    differed at step 3 (observation) after the recorder cast its actions (from step 0: dtype \
float64 cast to float32): the env stepped values the file holds rounded, so replay cannot step \
the same ones; give env.step() actions of the action space's dtype to make it replayable
    """
    if result.status != "diverged" or result.divergence is None:
        return result
    step = result.divergence.step
    if step is None or step < first:
        return result  # (it differed before any cast action was stepped)
    reason = (
        f"differed{_where(result.divergence)} after the recorder cast its actions (from step "
        f"{first}: {note}): the env stepped values the file holds rounded, so replay cannot "
        "step the same ones; give env.step() actions of the action space's dtype to make it "
        "replayable"
    )
    note_ = "" if result.reason is None else f" ({result.reason})"
    return replace(result, status="not_replayable", reason=reason + note_)


def not_told_from_history(
    result: EpisodeReplay, unrepeated: str, *, env: str = "this env"
) -> EpisodeReplay:
    """A diverged ``result`` ``not_replayable``: its env did before it what replay does not repeat.

    ``unrepeated`` says what (:func:`~.recorded.unrepeated`: a step or reset that raised, whose
    action is not recorded; steps after an episode's end). An env that keeps state across
    steps or resets began the episode elsewhere than replay's did, so its difference is no
    verdict. It keeps its first difference and what was restored.

    >>> d = EpisodeReplay("f", 2, "diverged", 0, Divergence(None, "reset_observation", "1", "0"))
    >>> print(not_told_from_history(d, "episode 1's 3 steps after its end").reason)
    differed at the reset (reset_observation) after calls to this env that replay does not \
repeat (episode 1's 3 steps after its end): the state it began from cannot be reproduced
    """
    if result.status != "diverged":
        return result
    reason = (
        f"differed{_where(result.divergence)} after calls to {env} that replay does not repeat "
        f"({unrepeated}): the state it began from cannot be reproduced"
    )
    note = "" if result.reason is None else f" ({result.reason})"
    return replace(result, status="not_replayable", reason=reason + note)


def not_told_unverified(episodes: Iterable[EpisodeReplay], cause: str) -> list[EpisodeReplay]:
    """``episodes`` with each diverged one ``not_replayable``: the env's match is unverified.

    ``cause`` says why the rebuilt env could not be held to the recording
    (:func:`~.mismatch.unverified_match`: an env factory's env without a spec, a wrapper that
    records no arguments): built otherwise, it differs with nothing wrong, so a difference is
    no verdict on the env. The episode keeps its first difference and what was restored.

    >>> d = EpisodeReplay("f", 0, "diverged", 3, Divergence(2, "reward", "1.0", "1.5"))
    >>> print(not_told_unverified([d], "the env factory's env has no spec")[0].reason)
    differed at step 2 (reward) in an env whose match with the recording could not be \
verified: the env factory's env has no spec
    """
    out = []
    for e in episodes:
        if e.status == "diverged":
            reason = f"differed{_where(e.divergence)}{_UNVERIFIED}{cause}"
            note = "" if e.reason is None else f" ({e.reason})"
            e = replace(e, status="not_replayable", reason=reason + note, unverified=cause)
        out.append(e)
    return out


_UNVERIFIED = " in an env whose match with the recording could not be verified: "


def _where(d: Divergence | None) -> str:
    """Where a difference is, as a not-replayable reason says it: `` at step 3 (reward)``."""
    if d is None:
        return ""
    return f" at {'the reset' if d.step is None else f'step {d.step}'} ({d.field})"


def env_error(exc: BaseException) -> str:
    """``"Type: message"`` of an exception the replay's env raised, as a divergence shows it.

    (Never raises: an exception whose ``str()`` raises says so.)
    """
    return f"{type(exc).__name__}: {error_message(exc)}"


class _Digest(str):
    """A digest-mode observation's BLAKE2b digest (``bytes`` decoded), shown in hex."""

    __slots__ = ()

    def __repr__(self) -> str:
        return f"digest {self}"


def _hex_digests(value: Any) -> Any:
    """``value`` with each ``bytes`` (a digest: no other observation decodes to bytes) in hex."""
    if isinstance(value, bytes):
        return _Digest(value.hex())
    if isinstance(value, Mapping):
        return {k: _hex_digests(v) for k, v in value.items()}
    if isinstance(value, tuple):
        return tuple(_hex_digests(v) for v in value)
    return value


def short(value: Any) -> str:
    """A value as a divergence shows it: its ``repr``, cut to 80 characters.

    A frame stored as its digest is shown as ``digest`` and the digest in hex. Never raises: a
    value whose ``repr()`` raises (an env's own object) is named by its type.

    >>> short({"frame": bytes(range(16)), "x": 1})
    "{'frame': digest 000102030405060708090a0b0c0d0e0f, 'x': 1}"
    """
    try:
        value = _hex_digests(value)
        if isinstance(value, np.ndarray) and value.size > 16:
            # (a camera frame's list would be millions of characters)
            text = np.array2string(value, threshold=16, edgeitems=2, separator=", ")
            text = " ".join(text.split())
        else:
            text = repr(value.tolist() if isinstance(value, np.ndarray) else value)
    except Exception as exc:
        text = f"<a {type(value).__name__} whose repr() raised {env_error(exc)}>"
    return text if len(text) <= 80 else text[:77] + "..."


def _numeric_difference(expected: Any, got: Any, atol: float) -> float | None:
    """The largest absolute difference of the numeric parts that differ, or ``None``.

    Parts are numeric arrays or numbers of the same shape (in a Dict or Tuple too), compared
    as replay compares them; any other part (text, a JSON value) is not a number.

    >>> _numeric_difference({"x": np.zeros(2), "t": "a"}, {"x": np.zeros(2), "t": "b"}, 0.0)
    >>> _numeric_difference({"x": np.zeros(2), "t": "a"}, {"x": np.ones(2) / 4, "t": "b"}, 0.0)
    0.25
    """
    if isinstance(expected, Mapping) and isinstance(got, Mapping):
        parts = [_numeric_difference(expected[k], got[k], atol) for k in expected if k in got]
    elif isinstance(expected, tuple) and isinstance(got, tuple) and len(expected) == len(got):
        parts = [_numeric_difference(e, g, atol) for e, g in zip(expected, got, strict=True)]
    else:
        if isinstance(expected, (str, bytes)) or isinstance(got, (str, bytes)):
            return None
        a, b = np.asarray(expected), np.asarray(got)
        if a.shape != b.shape or a.dtype.kind not in "biuf" or b.dtype.kind not in "biuf":
            return None
        a, b = a.reshape(-1), b.reshape(-1)
        differ = ~equal_elements(a, b, atol)
        if not differ.any():
            return None
        with np.errstate(all="ignore"):
            return float(np.max(np.abs(a[differ].astype(np.float64) - b[differ])))
    found = [d for d in parts if d is not None]
    return max(found) if found else None


def _first_difference(expected: Any, got: Any, atol: float, path: str = "") -> str | None:
    """Where two observations first differ, element by element, or ``None``.

    Only for numeric arrays (in a Dict or Tuple too) of the same shape: the index of the first
    element that differs (as replay compares: bitwise, NaN equal to NaN, or within ``atol``),
    both values, and how many elements differ.

    >>> _first_difference(np.zeros((2, 3)), np.array([[0, 0, 0], [0, 0.5, 0.25]]), 0.0)
    '[1, 1]: expected 0.0, got 0.5; 2 of 6 elements differ'
    >>> _first_difference({"pos": np.zeros(2)}, {"pos": np.ones(2)}, 0.0)
    "['pos'][0]: expected 0.0, got 1.0; 2 of 2 elements differ"
    """
    if isinstance(expected, Mapping) and isinstance(got, Mapping):
        for key in expected:
            if key in got:
                found = _first_difference(expected[key], got[key], atol, f"{path}[{key!r}]")
                if found is not None:
                    return found
        return None
    if isinstance(expected, tuple) and isinstance(got, tuple) and len(expected) == len(got):
        for i, (e, g) in enumerate(zip(expected, got, strict=True)):
            found = _first_difference(e, g, atol, f"{path}[{i}]")
            if found is not None:
                return found
        return None
    if not isinstance(expected, np.ndarray) or not isinstance(got, np.ndarray):
        return None
    if expected.shape != got.shape or expected.ndim == 0 or expected.dtype.kind not in "biuf":
        return None
    if got.dtype.kind not in "biuf":
        return None
    a, b = expected.reshape(-1), got.reshape(-1)
    differ = np.flatnonzero(~equal_elements(a, b, atol))
    if differ.size == 0:
        return None
    first = int(differ[0])
    index = ", ".join(str(int(i)) for i in np.unravel_index(first, expected.shape))
    return (
        f"{path}[{index}]: expected {a[first].item()!r}, got {b[first].item()!r}; "
        f"{differ.size} of {a.size} elements differ"
    )
