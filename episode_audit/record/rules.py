"""Where reward terms, success, failure labels and truncation reasons come from.

:class:`RewardTerms` says how a step's named reward terms are read from ``info``;
:class:`EndingRules` turns a final step's ``terminated`` / ``truncated`` / ``info`` into one
outcome of the taxonomy (``success``, ``failure``, ``truncated``; ``incomplete`` and ``error``
are decided by the recorder). Both describe themselves for the run metadata and are rebuilt
from that description (``from_description``). Values they read but do not expect are notes.

>>> RewardTerms().extract({"reward_dist": -0.2, "reward_ctrl": -0.1, "x": 3})
{'reward_dist': -0.2, 'reward_ctrl': -0.1}
>>> EndingRules().classify(True, False, {"success": True}, time_limit_hit=False)
Ending(outcome='success', failure_label=None, truncation_reason=None)
>>> EndingRules().classify(False, True, {}, time_limit_hit=True)
Ending(outcome='truncated', failure_label=None, truncation_reason='time_limit')
"""

from __future__ import annotations

import math
import numbers
import operator
from array import array
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple, TypeVar

import gymnasium as gym
import numpy as np

from ..errors import ConfigurationError
from ..format import names as fmt
from ..format.columns import PLAIN_NUMBERS, error_text, text
from .notes import note, short

__all__ = [
    "Ending",
    "EndingRules",
    "RewardTerms",
    "check_constants",
    "find_wrapper",
    "named_terms",
    "plain_names",
]

TermsFn = Callable[[Mapping[str, Any]], Mapping[str, float] | None]


@dataclass(frozen=True)
class RewardTerms:
    """How the named reward terms of a step are found in its ``info``.

    ``source`` is one of:

    - ``"auto"`` (default): ``info["reward_terms"]`` when it is a mapping, else every
      ``info["reward_*"]`` key (Gymnasium MuJoCo v5 style), else no terms;
    - a sequence of info keys, e.g. ``("reward_forward", "reward_ctrl")``;
    - a callable ``info -> {name: value}``;
    - ``None``: record no terms.

    ``constants`` declares terms an environment adds outside its info (e.g. a constant survival
    bonus): ``check`` adds them to every step's terms sum; they are not written per step.
    """

    source: str | Sequence[str] | TermsFn | None = "auto"
    constants: Mapping[str, float] = field(default_factory=dict)
    prefix: str = "reward_"
    dict_key: str = "reward_terms"

    def __post_init__(self) -> None:
        src = self.source
        keys = not isinstance(src, (str, bytes)) and isinstance(src, Sequence)
        if not (src is None or src == "auto" or callable(src) or keys):
            raise ConfigurationError(
                f"reward terms source: expected 'auto', a list of info keys, a callable or None, "
                f"actually: {src!r}"
            )
        check_constants(self.constants)

    def extract(self, info: Mapping[str, Any]) -> dict[str, Any] | None:
        """Return the step's terms (values not yet validated), or ``None`` when it has none."""
        return self.extractor(info)

    def extract_many(
        self, infos: Sequence[Mapping[str, Any]]
    ) -> tuple[tuple[str, ...], np.ndarray[Any, np.dtype[np.float64]]] | None:
        """The terms of many steps at once: ``(names, values)``, a float64 row per step.

        Only when :meth:`extract` would give every step the same names in the same order,
        each value a plain number; ``None`` otherwise (then ask :meth:`extract` step by step).

        >>> names, values = RewardTerms().extract_many([{"reward_a": 1.0}, {"reward_a": 2}])
        >>> names, values.tolist()
        (('reward_a',), [[1.0], [2.0]])
        """
        if not infos or self.source is None:
            return None
        key_sets = set(map(tuple, infos))
        if len(key_sets) != 1:
            return None
        (keys,) = key_sets
        names = self.names_for(keys)
        if not names:
            return None
        values = np.empty((len(names), len(infos)), dtype=np.float64)
        for i, name in enumerate(names):  # column by column: no tuple per step
            column = list(map(operator.itemgetter(name), infos))
            if not set(map(type, column)) <= PLAIN_NUMBERS:
                return None
            values[i] = array("d", column)
        return names, values.T

    def names_for(self, keys: tuple[Any, ...]) -> tuple[str, ...] | None:
        r"""The names :meth:`extract` reads from an info whose keys are ``keys`` (in order).

        ``()`` when such an info has no terms; ``None`` when only :meth:`extract` can tell
        (a callable source, or a ``reward_terms`` dict in the info) or when a name is not
        recorded as it is (not :func:`plain_names`: :func:`named_terms` names those). The
        recorder asks once per key tuple, then reads every step's terms with one ``itemgetter``.

        >>> RewardTerms().names_for(("reward_dist", "x", "reward_ctrl"))
        ('reward_dist', 'reward_ctrl')
        >>> RewardTerms(["b", "a"]).names_for(("a", "b", "c")), RewardTerms().names_for(("x",))
        (('b', 'a'), ())
        >>> RewardTerms().names_for(("reward_terms",)) is None
        True
        >>> RewardTerms().names_for(("reward_\udcff",)) is None  # stored escaped
        True
        """
        src = self.source
        if src is None:
            return ()
        if callable(src) and not isinstance(src, str):
            return None
        if src == "auto":
            if self.dict_key in keys:
                return None
            names = _prefixed(keys, self.prefix)
        else:
            present = set(keys)
            names = tuple(dict.fromkeys(k for k in src if k in present))  # as extract(): once
        return names if plain_names(names) else None

    @property
    def extractor(self) -> Callable[[Mapping[str, Any]], dict[str, Any] | None]:
        """:meth:`extract` as a plain function, for the per-step paths (built once)."""
        built: Callable[[Mapping[str, Any]], dict[str, Any] | None] | None = self.__dict__.get(
            "_extractor"
        )
        if built is None:
            built = self._build_extractor()
            object.__setattr__(self, "_extractor", built)  # frozen: a cache, not state
        return built

    def _build_extractor(self) -> Callable[[Mapping[str, Any]], dict[str, Any] | None]:
        src = self.source
        if src == "auto":
            return _auto_terms(self.dict_key, self.prefix)
        if src is None:
            return lambda info: None
        if callable(src):
            fn = src

            def from_callable(info: Mapping[str, Any]) -> dict[str, Any] | None:
                out = fn(info)
                return None if out is None else dict(out)

            return from_callable
        keys = tuple(src)
        return lambda info: {k: info[k] for k in keys if k in info} or None

    def describe(self) -> dict[str, Any]:
        """A JSON-able description for the run metadata."""
        src = self.source
        if callable(src) and not isinstance(src, str):
            kind: Any = f"callable:{getattr(src, '__qualname__', type(src).__name__)}"
        elif src is None or isinstance(src, str):
            kind = src
        else:
            kind = list(src)
        return {"source": kind, "constants": dict(self.constants)}

    @classmethod
    def from_description(cls, description: Mapping[str, Any] | None) -> RewardTerms | None:
        """The rule a run metadata's ``reward_terms`` describes: the inverse of :meth:`describe`.

        ``None`` for a callable source (``"callable:..."``: a file can only name it). A
        description without a source is ``"auto"``'s; the constants are kept (one that is not a
        finite number, which :meth:`describe` never gives, is a ``ConfigurationError``).

        >>> terms = RewardTerms.from_description({"source": ["b", "a"], "constants": {"c": 1.0}})
        >>> terms.source, terms.constants
        (('b', 'a'), {'c': 1.0})
        >>> RewardTerms.from_description({"source": "callable:my_terms"}) is None
        True
        """
        description = description or {}
        source = description.get("source", "auto")
        constants = dict(description.get("constants") or {})
        if source == "auto" or source is None:
            return cls(source, constants)
        if isinstance(source, list):
            return cls(tuple(str(k) for k in source), constants)
        return None  # a callable the file can only name


def check_constants(constants: Any) -> None:
    """Refuse constant terms that are not a mapping of names to finite numbers.

    >>> try:
    ...     check_constants({"alive": float("nan")})
    ... except ConfigurationError as exc:
    ...     print(exc)
    constant reward term 'alive': expected a finite number, actually: nan
    """
    if not isinstance(constants, Mapping):
        raise ConfigurationError(
            "constant reward terms: expected a mapping of names to numbers, e.g. "
            f"{{'alive_bonus': 1.0}}, actually: {type(constants).__name__}"
        )
    for name, value in constants.items():
        if not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigurationError(
                f"constant reward term {name!r}: expected a finite number, actually: {value!r}"
            )


def _prefixed(keys: Sequence[Any], prefix: str) -> tuple[str, ...]:
    """The keys that are names starting with ``prefix``, in order."""
    return tuple(k for k in keys if isinstance(k, str) and k.startswith(prefix))


def plain_names(names: Iterable[Any]) -> bool:
    r"""Whether every name is recorded as it is: a ``str`` (not a subclass) UTF-8 can encode.

    Such a name is its own :func:`term_name`, so distinct ones never collide; the recorder
    and replay hand only other names to :func:`named_terms`.

    >>> plain_names(["reward_a", "é"]), plain_names([b"a"]), plain_names(["a\udcff"])
    (True, False, False)
    """
    names = tuple(names)
    if not set(map(type, names)) <= _STR:
        return False
    try:
        "".join(names).encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


_STR = frozenset({str})


def term_name(key: Any) -> str:
    r"""The name a reward term's key is recorded under; never raises.

    A ``str`` as it is, anything else its ``str()`` (so ``b"a"`` is ``"b'a'"``: bytes are not
    decoded, as no other name is guessed at), through :func:`~episode_audit.format.columns.text`
    (text UTF-8 cannot encode is escaped). A key whose ``str()`` raises is named after its type.

    >>> term_name("dist"), term_name(b"a"), term_name(1), term_name("a\udcff")
    ('dist', "b'a'", '1', 'a\\udcff')
    """
    try:
        return text(key)
    except Exception as exc:
        return f"<{type(key).__name__}: str() raised {type(exc).__name__}>"


def named_terms(
    keys: Sequence[Any], values: Sequence[float]
) -> tuple[dict[str, float], str | None]:
    """A step's terms by the name each key is recorded under (:func:`term_name`).

    Keys that share a name (``1`` and ``"1"``, ``b"a"`` and ``"b'a'"``) are one term, the sum
    of their values, where the first of them was; the second item then says which keys, for
    the ``terms_name_collision`` note (else ``None``). The recorder's two paths and replay
    all name terms with this, so a file replays as it was recorded.

    >>> named_terms([1, "x", "1"], [0.5, 2.0, 0.25])
    ({'1': 0.75, 'x': 2.0}, "keys 1, '1' share the name '1': recorded as one term, their sum")
    """
    terms: dict[str, float] = {}
    shared: list[str] = []
    for key, value in zip(keys, values, strict=True):
        name = term_name(key)
        if name in terms:
            if name not in shared:
                shared.append(name)
            terms[name] += value
        else:
            terms[name] = value
    if not shared:
        return terms, None
    why = "; ".join(
        f"keys {', '.join(short(k) for k in keys if term_name(k) == name)} share the name "
        f"{short(name)}: recorded as one term, their sum"
        for name in shared
    )
    return terms, why


def _auto_terms(dict_key: str, prefix: str) -> Callable[[Mapping[str, Any]], dict[str, Any] | None]:
    """The ``"auto"`` rule: ``info[dict_key]`` if it is there, else the ``prefix*`` keys.

    Which keys carry the prefix is remembered per key tuple (envs return the same keys step
    after step), so a step costs a tuple and a lookup, not a scan of every key.
    """
    names_of: dict[tuple[Any, ...], tuple[str, ...]] = {}

    def extract(info: Mapping[str, Any]) -> dict[str, Any] | None:
        terms = info.get(dict_key)
        if terms is not None:
            return dict(terms)
        if not info:
            return None
        keys = tuple(info)
        names = names_of.get(keys)
        if names is None:
            names = _prefixed(keys, prefix)
            if len(names_of) < 64:  # bounded: an env with ever-new keys is scanned each time
                names_of[keys] = names
        return {k: info[k] for k in names} if names else None

    return extract


class Ending(NamedTuple):
    """The outcome of an episode that ended by ``terminated`` or ``truncated``."""

    outcome: str
    failure_label: str | None
    truncation_reason: str | None


SuccessFn = Callable[[Mapping[str, Any]], bool]
FailureFn = Callable[[Mapping[str, Any]], str | None]


@dataclass(frozen=True)
class EndingRules:
    """How success, failure labels and truncation reasons are read from the final ``info``.

    Defaults follow the conventions of SB3 and Gymnasium-Robotics: ``info["success"]`` or
    ``info["is_success"]`` for success, ``info["failure"]`` for a failure label (a string; any
    other truthy value means a failure without a label), ``info["truncation_reason"]`` for an
    env-given truncation reason. ``success_fn`` / ``failure_fn`` replace the key lookups.

    A terminated episode is a ``success`` when the success predicate holds, else a ``failure``
    (``unlabeled`` when no label is given). A truncated, not terminated, episode is
    ``truncated`` with the env-given reason, else ``time_limit`` when one of Gymnasium's
    ``TimeLimit`` wrappers reached its limit, else ``external``. When both flags are set, the
    task ending counts and the truncation reason is kept beside it.

    A success value is taken by its truth value, whatever it is; one that is not a bool or a
    real number (the text ``"no"``, which is true) is a ``success_not_bool`` note. A failure
    label that is neither text nor a bool (an int, an Enum member) is a failure without a label
    and a ``failure_label_not_text`` note; a truncation reason that is neither text nor a bool,
    the reason given without one (``time_limit`` / ``external``) and a
    ``truncation_reason_not_text`` note. See :meth:`classify_or_note`.
    """

    success_keys: Sequence[str] = ("success", "is_success")
    failure_key: str = "failure"
    truncation_reason_key: str = "truncation_reason"
    success_fn: SuccessFn | None = None
    failure_fn: FailureFn | None = None

    def is_success(self, info: Mapping[str, Any]) -> bool:
        """Whether the success predicate holds for this final ``info``."""
        return self._success(info, None)

    def reports_success(self, info: Any) -> bool:
        """Whether this final ``info`` says anything about success, true or false.

        Always true with a ``success_fn``. A task whose endings never do (CartPole, Hopper:
        no success key in their infos) has no success to be missing, and ``report`` does not
        warn that it is.

        >>> EndingRules().reports_success({"is_success": False}), EndingRules().reports_success({})
        (True, False)
        """
        if self.success_fn is not None:
            return True
        try:
            return any(info.get(key) is not None for key in self.success_keys)
        except Exception:  # an info that is not a mapping, or one whose get() raises
            return False

    def _success(self, info: Mapping[str, Any], notes: list[str] | None) -> bool:
        """:meth:`is_success`; a value that is not a bool or a number is noted in ``notes``."""
        value: Any
        if self.success_fn is not None:
            value, source = self.success_fn(info), "success_fn returned"
        else:
            for key in self.success_keys:
                value = info.get(key)
                if value is not None:
                    source = f"info[{short(key)}] is"
                    break
            else:
                return False
        truth = bool(value)  # may raise (an array): the ending is unreadable
        if notes is not None and not _truth_value(value):
            taken = "a success" if truth else "not a success"
            notes.append(
                note(
                    "success_not_bool",
                    f"{source} {_shown(value)}: taken by its truth value as {taken}",
                )
            )
        return truth

    def failure_label(self, info: Mapping[str, Any]) -> str:
        """The failure label of a terminal failure (``unlabeled`` when none is given)."""
        return self._failure_label(info, None)

    def _failure_label(self, info: Mapping[str, Any], notes: list[str] | None) -> str:
        """:meth:`failure_label`; a label that is not text nor a bool is noted in ``notes``."""
        if self.failure_fn is not None:
            label, source = self.failure_fn(info), "failure_fn returned"
        else:
            label, source = info.get(self.failure_key), f"info[{short(self.failure_key)}] is"
        if isinstance(label, str) and label:
            return text(label)
        if notes is not None and not _no_label(label):
            hint = "return a string" if self.failure_fn else "give a string, or pass failure_fn"
            notes.append(
                note(
                    "failure_label_not_text",
                    f"{source} {_shown(label)}: recorded as unlabeled; {hint}",
                )
            )
        return fmt.UNLABELED

    def truncation_reason(self, info: Mapping[str, Any], *, time_limit_hit: bool) -> str:
        """The reason a truncated episode was cut off."""
        return self._truncation_reason(info, time_limit_hit, None)

    def _truncation_reason(
        self, info: Mapping[str, Any], time_limit_hit: bool, notes: list[str] | None
    ) -> str:
        """:meth:`truncation_reason`; a reason that is not text nor a bool is noted in ``notes``.

        As a failure label (:meth:`_failure_label`): ``True`` says "cut off" and no more, as
        the flag does, so nothing the env said is lost; an Enum member or a code is.
        """
        reason = info.get(self.truncation_reason_key)
        if isinstance(reason, str) and reason:
            return text(reason)
        taken = fmt.REASON_TIME_LIMIT if time_limit_hit else fmt.REASON_EXTERNAL
        if notes is not None and not _no_label(reason):
            notes.append(
                note(
                    "truncation_reason_not_text",
                    f"info[{short(self.truncation_reason_key)}] is {_shown(reason)}: "
                    f"recorded as {taken}; give a string",
                )
            )
        return taken

    def classify(
        self, terminated: bool, truncated: bool, info: Mapping[str, Any], *, time_limit_hit: bool
    ) -> Ending:
        """Classify a final step (at least one of the flags must be set)."""
        return self._classify(terminated, truncated, info, time_limit_hit, None)

    def _classify(
        self,
        terminated: bool,
        truncated: bool,
        info: Mapping[str, Any],
        time_limit_hit: bool,
        notes: list[str] | None,
    ) -> Ending:
        """:meth:`classify`; what the values read deserve is noted in ``notes`` (if given)."""
        reason = self._truncation_reason(info, time_limit_hit, notes) if truncated else None
        if terminated:
            if self._success(info, notes):
                return Ending(fmt.OUTCOME_SUCCESS, None, reason)
            return Ending(fmt.OUTCOME_FAILURE, self._failure_label(info, notes), reason)
        if truncated:
            return Ending(fmt.OUTCOME_TRUNCATED, None, reason)
        raise ConfigurationError("classify() needs terminated or truncated to be set")

    def classify_or_note(
        self,
        terminated: bool,
        truncated: bool,
        info: Any,
        *,
        time_limit_hit: bool,
        notes: list[str] | None = None,
    ) -> tuple[Ending, str | None]:
        """:meth:`classify` and ``None``, or the ending by the flags alone and why.

        The second is for a final ``info`` that cannot be read: not a mapping, a success
        value whose truth is ambiguous, a ``success_fn`` / ``failure_fn`` that raises.

        With ``notes``, values that were read but are not what the rules expect are appended
        to it as recorder notes (:func:`note`): ``success_not_bool``, a success value that is
        not a bool or a real number (a 0-d array of one counts as one; NaN does not), taken by
        its truth value; ``failure_label_not_text``, a true failure label that is not a
        non-empty string nor a bool, recorded as ``unlabeled``; ``truncation_reason_not_text``,
        a true truncation reason that is not a non-empty string nor a bool, recorded as the
        reason given without one. The ending is :meth:`classify`'s either way. An empty string,
        ``None``, ``False`` or ``0`` is no label (no reason), ``True`` a failure without a label
        (a truncation without a reason): not noted.

        The recorder and replay both classify this way, so neither raises over an env's info.

        >>> import numpy as np
        >>> ending, why = EndingRules().classify_or_note(
        ...     True, False, {"success": np.ones(2)}, time_limit_hit=False
        ... )
        >>> ending.outcome, ending.failure_label, why[:40]
        ('failure', 'unlabeled', 'ValueError: The truth value of an array ')
        >>> notes = []
        >>> EndingRules().classify_or_note(
        ...     True, False, {"success": "no"}, time_limit_hit=False, notes=notes
        ... )
        (Ending(outcome='success', failure_label=None, truncation_reason=None), None)
        >>> notes
        ["success_not_bool: info['success'] is 'no' (str): taken by its truth value as a success"]
        """
        read: list[str] | None = None if notes is None else []
        try:
            if not isinstance(info, Mapping):
                raise TypeError(f"info is a {type(info).__name__}, not a dict")
            ending = self._classify(terminated, truncated, info, time_limit_hit, read)
        except Exception as exc:
            why = error_text(exc)  # nothing read counts: no notes but this one
        else:
            if notes is not None and read:
                notes.extend(read)
            return ending, None
        # by the flags alone: the default rules over an empty info (no user functions)
        return _BY_FLAGS.classify(terminated, truncated, {}, time_limit_hit=time_limit_hit), why

    def flag_endings(self) -> tuple[dict[tuple[bool, bool, bool], Ending], frozenset[str]]:
        """Each final step's ending by its flags alone, and the ``info`` keys these rules read.

        A final step whose ``info`` (a ``dict``) holds none of the keys ends as the table says
        for ``(terminated, truncated, time_limit_hit)``: the common case (CartPole, MuJoCo),
        made once per stream. The table is empty when more than keys decide (a ``success_fn`` /
        ``failure_fn``, a subclass): :meth:`classify` every ending then.

        >>> endings, keys = EndingRules().flag_endings()
        >>> endings[True, False, False]
        Ending(outcome='failure', failure_label='unlabeled', truncation_reason=None)
        >>> endings[False, True, True].truncation_reason, sorted(keys)[:2]
        ('time_limit', ['failure', 'is_success'])
        """
        endings: dict[tuple[bool, bool, bool], Ending] = {}
        if type(self) is EndingRules and self.success_fn is None and self.failure_fn is None:
            for terminated, truncated in ((True, False), (False, True), (True, True)):
                for hit in (False, True):
                    ending = self._classify(terminated, truncated, {}, hit, None)
                    endings[terminated, truncated, hit] = ending
        keys = frozenset((*self.success_keys, self.failure_key, self.truncation_reason_key))
        return endings, keys

    def describe(self) -> dict[str, Any]:
        """A JSON-able description for the run metadata."""
        return {
            "success_keys": list(self.success_keys),
            "failure_key": self.failure_key,
            "truncation_reason_key": self.truncation_reason_key,
            "success_fn": _fn_name(self.success_fn),
            "failure_fn": _fn_name(self.failure_fn),
        }

    @classmethod
    def from_description(cls, description: Mapping[str, Any] | None) -> EndingRules | None:
        """The rules a run metadata's ``ending_rules`` describes: the inverse of :meth:`describe`.

        ``None`` when it names a ``success_fn`` or ``failure_fn`` (a callable cannot be rebuilt
        from a file). A key that is missing (or null) takes its default.

        >>> rules = EndingRules.from_description({"success_keys": ["done"], "failure_key": "why"})
        >>> rules.success_keys, rules.failure_key, rules.truncation_reason_key
        (('done',), 'why', 'truncation_reason')
        >>> EndingRules.from_description({"success_fn": "my_success"}) is None
        True
        """
        description = description or {}
        if description.get("success_fn") or description.get("failure_fn"):
            return None
        default = cls()

        def given(key: str, value: Any) -> Any:
            found = description.get(key)
            return value if found is None else found

        return cls(
            success_keys=tuple(given("success_keys", default.success_keys)),
            failure_key=str(given("failure_key", default.failure_key)),
            truncation_reason_key=str(
                given("truncation_reason_key", default.truncation_reason_key)
            ),
        )


_BY_FLAGS = EndingRules()
"""Rules that read nothing from an info: with an empty one, the ending the flags alone give."""

_BOOLS = frozenset({bool, np.bool_})
_TRUTH_TYPES = frozenset({bool, np.bool_, int, float, np.float64, np.float32})
"""The usual success values: bools and numbers (checked first, by type, for speed)."""


def _truth_value(value: Any) -> bool:
    """Whether ``value`` is a bool or a real number (not NaN), numpy's included.

    A 0-d numpy array of one counts as one: it has one truth value, as the scalar has.
    """
    if type(value) not in _TRUTH_TYPES:
        if isinstance(value, np.ndarray) and value.ndim == 0:
            value = value[()]
        if not isinstance(value, (numbers.Real, np.bool_)):
            return False
    try:
        return not math.isnan(value)
    except Exception:  # a Real whose float() fails: taken as it is
        return True


def _no_label(label: Any) -> bool:
    """Whether a failure label (or truncation reason) that is not text goes without a note.

    A bool (``True`` is the documented "a failure without a label") or a false value (``None``,
    ``""``, ``0``) does; a value without a single truth value (an array) is noted.
    """
    if type(label) in _BOOLS:
        return True
    try:
        return not label
    except Exception:
        return False


def _shown(value: Any) -> str:
    """``repr`` (cut) and type of a value, for a note: ``'no' (str)``."""
    return f"{short(value)} ({type(value).__name__})"


def _fn_name(fn: Callable[..., Any] | None) -> str | None:
    return None if fn is None else getattr(fn, "__qualname__", type(fn).__name__)


_W = TypeVar("_W", bound=gym.Wrapper[Any, Any, Any, Any])


def find_wrapper(env: Any, kind: type[_W]) -> _W | None:
    """The outermost wrapper of type ``kind`` around ``env`` (``env`` itself included), if any."""
    current = env
    while isinstance(current, gym.Wrapper):
        if isinstance(current, kind):
            return current
        current = current.env
    return None
