"""Compare replayed episodes with their evidence: the first difference, and the outcome.

:class:`Comparison` compares a file's stepped episodes with the recorded steps over whole
columns at once (observations, rewards, reward terms, flags) and looks at an episode on its own
only where it differs; :func:`outcome_difference` compares an episode's replayed ending with
its recorded outcome; :func:`terms_equal` compares one row's reward terms. What is compared, and
how: docs/replay.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from ..format import names as fmt
from ..format.columns import null_mask, one_array
from ..format.spaces import SpaceCodec
from ..record.rules import Ending, EndingRules, RewardTerms
from .results import Divergence, EpisodeReplay, short
from .returned import Got, Ran, Stepped, Steps

__all__ = ["Comparison", "outcome_difference", "terms_equal"]

_FLAG_NAMES = ("False", "True", "not a bool")
_NOT_ENDED = (fmt.OUTCOME_INCOMPLETE, fmt.OUTCOME_ERROR)
_Fields = list[tuple[str, np.ndarray[Any, Any], np.ndarray[Any, Any] | None]]
"""Per compared field: its name, the rows where it is equal, and the absolute differences."""


class Comparison:
    """Compares the stepped episodes of one file with its evidence."""

    def __init__(
        self,
        file: str,
        obs_codec: SpaceCodec,
        *,
        atol: float,
        rules: EndingRules | None,
        terms_rule: RewardTerms | None,
        unread_limits: str | None = None,
    ) -> None:
        self.file = file
        self.obs_codec = obs_codec
        self.atol = atol
        self.rules = rules
        self.terms_rule = terms_rule
        self.unread_limits = unread_limits
        """Why the recorder could not read every ``TimeLimit`` (``wrappers.unread_limits``)."""
        self._plain_endings: dict[tuple[bool, bool, bool], Ending] = {}

    def _diverged(self, index: int, steps: int, divergence: Divergence) -> EpisodeReplay:
        return EpisodeReplay(self.file, index, "diverged", steps, divergence)

    def _differs(self, episode: Stepped, steps: int, divergence: Divergence) -> EpisodeReplay:
        """``episode`` diverged, unless the time limits explain it (:func:`_limit_ending`).

        Such a difference is ``not_replayable``, keeping its first difference: a ``TimeLimit``
        counts steps whatever the env does, so the rebuilt env's reaching its limit where the
        recording's did not (or the other way) says the limits differ, not the env.
        """
        index = int(episode.record["episode"])
        why = _limit_ending(episode, divergence, unread=self.unread_limits is not None)
        if why is None:
            return self._diverged(index, steps, divergence)
        reason = f"{why}: {self.unread_limits or _LIMITS_DIFFER}"
        return EpisodeReplay(self.file, index, "not_replayable", steps, divergence, reason)

    def episodes(
        self,
        ran: Ran,
        returned: Steps,
        got_obs: pa.Array,
        got_reset: pa.Array,
        steps: pa.Table,
        resets: pa.Table,
        done: dict[int, EpisodeReplay],
    ) -> None:
        """Compare the stepped episodes with the evidence; put each one's result in ``done``."""
        obs_codec = self.obs_codec
        starts = np.array(ran.starts, dtype=np.int64)
        counts = np.array(ran.counts, dtype=np.int64)
        steps_ran = np.array(ran.ran, dtype=np.int64)
        firsts = np.cumsum(counts) - counts
        take = np.repeat(starts - firsts, counts) + np.arange(int(counts.sum()))
        same_rows = take.size == steps.num_rows and bool((take == np.arange(take.size)).all())
        expected = steps if same_rows else steps.take(pa.array(take))
        got = Got.collect(returned, steps_ran, firsts, got_obs, expected.num_rows, self.terms_rule)
        bad, field_masks = self._mismatches(expected, got)
        reset_obs = one_array(resets.column(fmt.COL_OBSERVATION))
        reset_equal, reset_diff = obs_codec.compare(
            reset_obs.take(pa.array(ran.reset_at, pa.int64())), got_reset, atol=self.atol
        )
        first_bad = np.append(bad, np.iinfo(np.int64).max)[np.searchsorted(bad, firsts)]
        # clean: the reset and every compared row match, all rows ran, nothing raised
        clean = reset_equal & (first_bad >= firsts + steps_ran) & (steps_ran == counts)
        if ran.crashes:
            clean[list(ran.crashes)] = False
        last_term, last_trunc = _last_flags(got, firsts, steps_ran)
        file, outcome_difference = self.file, self.outcome_difference
        checks_outcome, plain = self.rules is not None, self._plain_endings
        for k, (record, is_clean, n, term, trunc) in enumerate(
            zip(ran.records, clean.tolist(), ran.ran, last_term, last_trunc, strict=True)
        ):
            index = record["episode"]
            if is_clean:
                outcome = None
                info = ran.last_infos[k]
                if n and not (
                    # the usual case, without a call: an outcome already classified the same
                    checks_outcome
                    and type(info) is dict
                    and not info
                    and plain.get((term == 1, trunc == 1, ran.hits[k])) == _recorded_outcome(record)
                ):
                    outcome = outcome_difference(
                        record, term == 1, trunc == 1, n - 1, info, ran.hits[k]
                    )
                done[index] = (
                    EpisodeReplay(file, index, "identical", n)
                    if outcome is None
                    else self._differs(ran.episode(k, int(firsts[k])), n, outcome)
                )
            elif not reset_equal[k]:
                expected_reset = reset_obs.slice(ran.reset_at[k], 1)
                divergence = self._reset_divergence(
                    expected_reset, got_reset.slice(k, 1), float(reset_diff[k])
                )
                done[index] = self._diverged(index, 0, divergence)
            else:
                episode = ran.episode(k, int(firsts[k]))
                done[index] = self._verdict(episode, int(first_bad[k]), field_masks, expected, got)

    def _reset_divergence(self, expected: pa.Array, got: pa.Array, diff: float) -> Divergence:
        """The reset observations (one row each) differ."""
        exp = self.obs_codec.decode(expected)[0]
        now = self.obs_codec.decode(got)[0]
        return Divergence.of_observation(None, exp, now, diff, self.atol)

    def _mismatches(self, expected: pa.Table, got: Got) -> tuple[np.ndarray[Any, Any], _Fields]:
        """Rows that differ in any field, and per field (name, equal mask, abs diff)."""
        n = expected.num_rows
        obs_equal, obs_diff = self.obs_codec.compare(
            expected.column(fmt.COL_OBSERVATION), got.obs, atol=self.atol
        )
        exp_r = expected.column(fmt.COL_REWARD).to_numpy()
        got_r = got.rewards
        with np.errstate(invalid="ignore"):
            diff_r = np.abs(exp_r - got_r)
            same_r = (exp_r == got_r) | (np.isnan(exp_r) & np.isnan(got_r)) | (diff_r <= self.atol)
        fields: _Fields = [("observation", obs_equal, obs_diff), ("reward", same_r, diff_r)]
        if self.terms_rule is not None:
            fields.append(("terms", self._terms_equal(expected, got.terms.column(), n), None))
        for name, flags in (
            (fmt.COL_TERMINATED, got.terminated),
            (fmt.COL_TRUNCATED, got.truncated),
        ):
            exp = expected.column(name).to_numpy(zero_copy_only=False).astype(np.int8)
            fields.append((name, exp == flags, None))
        ok = np.ones(n, dtype=np.bool_)
        for _, equal, _ in fields:
            ok &= equal
        return np.flatnonzero(~ok), fields

    def _terms_equal(self, expected: pa.Table, got: pa.Array, n: int) -> np.ndarray[Any, Any]:
        exp = one_array(expected.column(fmt.COL_TERMS))
        if exp.null_count == n and got.null_count == n:
            return np.ones(n, dtype=np.bool_)
        return _terms_rows_equal(exp, got, self.atol)

    def _verdict(
        self, episode: Stepped, first_bad: int, fields: _Fields, expected: pa.Table, got: Got
    ) -> EpisodeReplay:
        """An episode that is not clean: its first differing row, crash, length or outcome."""
        record, first, count, ran = episode.record, episode.first, episode.count, episode.ran
        index = int(record["episode"])
        if first_bad < first + ran:
            step = first_bad - first
            divergence = self._row_divergence(first_bad, step, fields, expected, got)
            return self._differs(episode, step, divergence)
        if episode.crash is not None:
            return self._diverged(index, ran, episode.crash)
        if ran < count:
            return self._differs(
                episode,
                ran,
                Divergence(ran, "length", f"{count} steps", f"the episode ended after {ran}"),
            )
        if ran:
            last = first + ran - 1
            outcome = self.outcome_difference(
                record,
                bool(got.terminated[last] == 1),
                bool(got.truncated[last] == 1),
                ran - 1,
                episode.last_info,
                episode.hit_time_limit,
            )
            if outcome is not None:
                return self._differs(episode, ran, outcome)
        return EpisodeReplay(self.file, index, "identical", ran)

    def _row_divergence(
        self, row: int, step: int, fields: _Fields, expected: pa.Table, got: Got
    ) -> Divergence:
        """How compared row ``row`` (the episode's ``step``) differs: its first differing field."""
        name, _, diff = next(f for f in fields if not f[1][row])
        d = None if diff is None else float(diff[row])
        if name == "observation":
            col = expected.column(fmt.COL_OBSERVATION)
            exp_obs = self.obs_codec.decode(one_array(col.slice(row, 1)))[0]
            got_obs = self.obs_codec.decode(got.obs.slice(row, 1))[0]
            return Divergence.of_observation(step, exp_obs, got_obs, d, self.atol)
        if name == "reward":
            exp_v = repr(expected.column(fmt.COL_REWARD)[row].as_py())
            got_v = repr(float(got.rewards[row]))
            refused = got.reward_errors.get(row)
            if refused is not None:  # (the recorder would have recorded NaN)
                got_v, d = f"a reward that is not a number (float() raised {refused})", None
        elif name == "terms":
            exp_v = short(dict(expected.column(fmt.COL_TERMS)[row].as_py() or []))
            got_v = short(got.terms.at(row))
        else:
            flags = got.terminated if name == fmt.COL_TERMINATED else got.truncated
            exp_v = str(expected.column(name)[row].as_py())
            got_v = _FLAG_NAMES[int(flags[row])]
        return Divergence(step, name, exp_v, got_v, d)

    def outcome_difference(
        self,
        record: dict[str, Any],
        term: bool,
        trunc: bool,
        last_step: int,
        info: Any,
        hit_time_limit: bool,
    ) -> Divergence | None:
        """:func:`outcome_difference` under this file's rules (one classification per flags)."""
        return outcome_difference(
            self.rules,
            record,
            term,
            trunc,
            last_step,
            info,
            time_limit_hit=hit_time_limit,
            endings=self._plain_endings,
            unread_limits=self.unread_limits is not None,
        )


_LIMITS_DIFFER = (
    "the rebuilt env's TimeLimits are not those it was recorded in (a limit set after the "
    "recorder was made, say); build it with the limits it ran under"
)


def _limit_ending(episode: Stepped, divergence: Divergence, *, unread: bool) -> str | None:
    """How the time limits explain ``divergence``, or ``None``.

    The difference is where the recording's or the rebuilt env's ``TimeLimit`` ended the
    episode, and the other's did not. The recording's: the episode was recorded truncated
    ``time_limit`` at its last step, and the rebuilt env's limits were not reached there. The
    rebuilt env's: its time limit truncated the episode before its recorded end (differing no
    earlier), or at its recorded last step, where the recording did not say ``time_limit``.
    And, when the recorder could not read every ``TimeLimit`` (``unread``), a truncation it
    recorded as ``external`` at the last step, where the rebuilt env did not truncate.
    """
    last, ran, step = episode.count - 1, episode.ran, divergence.step
    reason = episode.record.get("truncation_reason")
    hit = episode.hit_time_limit
    at_end = step == last and ran == episode.count
    flags = divergence.field in (fmt.COL_TRUNCATED, "outcome")
    if at_end and flags and reason == fmt.REASON_TIME_LIMIT and not hit:
        return (
            f"recorded truncated by its time limit at step {last}, where the rebuilt env's "
            "limits were not reached"
        )
    if at_end and flags and hit and reason != fmt.REASON_TIME_LIMIT:
        return (
            f"the rebuilt env's time limit truncated it at step {last}, where the recording's "
            "did not"
        )
    if hit and ran <= last and step is not None and step >= ran - 1:
        return (
            f"the rebuilt env's time limit truncated it at step {ran - 1}, where the recorded "
            "episode went on"
        )
    if (
        unread
        and at_end
        and divergence.field == fmt.COL_TRUNCATED
        and reason == fmt.REASON_EXTERNAL
    ):
        return (
            f"recorded truncated (external) at step {last}, where the rebuilt env did not truncate"
        )
    return None


def _last_flags(
    got: Got, firsts: np.ndarray[Any, Any], steps_ran: np.ndarray[Any, Any]
) -> tuple[list[int], list[int]]:
    """The replayed ``terminated`` and ``truncated`` of each episode's last step (0: none)."""
    lasts = (firsts + steps_ran - 1)[steps_ran > 0]
    last_term = np.zeros(len(firsts), dtype=np.int8)
    last_trunc = np.zeros(len(firsts), dtype=np.int8)
    last_term[steps_ran > 0] = got.terminated[lasts]
    last_trunc[steps_ran > 0] = got.truncated[lasts]
    return last_term.tolist(), last_trunc.tolist()


def outcome_difference(
    rules: EndingRules | None,
    record: Mapping[str, Any],
    terminated: bool,
    truncated: bool,
    last_step: int,
    info: Any,
    *,
    time_limit_hit: bool,
    endings: dict[tuple[bool, bool, bool], Ending] | None = None,
    unread_limits: bool = False,
) -> Divergence | None:
    """How the outcome of an episode whose last step was ``last_step`` differs, if it does.

    Not compared without ``rules``, for an episode recorded as incomplete or error, or when its
    last step set neither flag. The ending is classified as the recorder's
    ``Stream._end_by_flags`` classifies it (:func:`_final_ending`); ``endings`` (optional)
    keeps the ending of an empty-dict info per flags, so it is classified once.
    ``unread_limits``: the recorder could not read every ``TimeLimit`` (the file's layout says
    so), so a truncation by one it recorded ``external``: the rebuilt env's time limit
    truncating the episode there is that ending (:func:`_as_recorder_saw`).
    """
    if rules is None or record["outcome"] in _NOT_ENDED:
        return None
    if not (terminated or truncated):
        return None
    if endings is not None and type(info) is dict and not info:  # the usual case
        key = (terminated, truncated, time_limit_hit)
        ending = endings.get(key)
        if ending is None:
            ending = endings[key] = rules.classify(
                terminated, truncated, {}, time_limit_hit=time_limit_hit
            )
    else:
        ending = _final_ending(rules, terminated, truncated, info, time_limit_hit=time_limit_hit)
    want = _recorded_outcome(record)
    now = (ending.outcome, ending.failure_label, ending.truncation_reason)
    if unread_limits and time_limit_hit:
        now = _as_recorder_saw(now, want)
    if want != now:
        return Divergence(last_step, "outcome", _fmt_outcome(*want), _fmt_outcome(*now))
    return None


def _as_recorder_saw(now: tuple[Any, Any, Any], want: tuple[Any, Any, Any]) -> tuple[Any, Any, Any]:
    """A replayed ending ``now`` by a time limit, as a recorder that could not read it said it.

    Where the recorded ending (``want``) is an ``external`` truncation, that recorder saw the
    same flags with no limit reached: ``time_limit`` is then ``external``. Any other ending is
    as it is.
    """
    if now[2] == fmt.REASON_TIME_LIMIT and want[2] == fmt.REASON_EXTERNAL:
        return (now[0], now[1], fmt.REASON_EXTERNAL)
    return now


def _final_ending(
    rules: EndingRules, terminated: bool, truncated: bool, info: Any, *, time_limit_hit: bool
) -> Ending:
    """A final step's ending as the recorder's ``Stream._end_by_flags`` classifies it.

    An info that is not a mapping is read as an empty one; one the rules cannot read (a success
    value with no single truth value, an array) gives the ending by the flags alone
    (:meth:`~episode_audit.record.rules.EndingRules.classify_or_note`). Never raises.
    """
    ending, _ = rules.classify_or_note(
        terminated,
        truncated,
        info if isinstance(info, Mapping) else {},
        time_limit_hit=time_limit_hit,
    )
    return ending


def _recorded_outcome(record: Mapping[str, Any]) -> tuple[Any, Any, Any]:
    """An episode record's (outcome, failure label, truncation reason), as an ``Ending`` is."""
    return record["outcome"], record.get("failure_label"), record.get("truncation_reason")


def _fmt_outcome(outcome: str, label: str | None, reason: str | None) -> str:
    parts = [outcome] + [p for p in (label, reason) if p]
    return "/".join(parts)


def _terms_rows_equal(exp: pa.Array, got: pa.Array, atol: float) -> np.ndarray[Any, Any]:
    """Per row of two ``terms`` map columns, what :func:`terms_equal` says, over whole columns.

    Rows are equal when both are null, or both hold the same names in the same order with
    values equal (NaN equals NaN; within ``atol`` when it is positive; a null value equals
    only a null value).
    """
    exp_null, got_null = null_mask(exp), null_mask(got)
    exp_off = exp.offsets.to_numpy(zero_copy_only=False).astype(np.int64)
    got_off = got.offsets.to_numpy(zero_copy_only=False).astype(np.int64)
    exp_len, got_len = np.diff(exp_off), np.diff(got_off)
    both = ~exp_null & ~got_null
    equal: np.ndarray[Any, Any] = (exp_null == got_null) & (~both | (exp_len == got_len))
    rows = np.flatnonzero(both & (exp_len == got_len) & (exp_len > 0))
    if rows.size == 0:
        return equal
    # the flat positions of every compared (name, value) pair, row after row
    lens = exp_len[rows]
    within = np.arange(int(lens.sum())) - np.repeat(np.cumsum(lens) - lens, lens)
    exp_at = pa.array(np.repeat(exp_off[rows], lens) + within)
    got_at = pa.array(np.repeat(got_off[rows], lens) + within)
    keys = pc.equal(exp.keys.take(exp_at), got.keys.take(got_at)).fill_null(False)
    same = keys.to_numpy(zero_copy_only=False)
    exp_v, got_v = exp.items.take(exp_at), got.items.take(got_at)
    a = exp_v.to_numpy(zero_copy_only=False).astype(np.float64)
    b = got_v.to_numpy(zero_copy_only=False).astype(np.float64)
    a_null, b_null = null_mask(exp_v), null_mask(got_v)
    with np.errstate(invalid="ignore"):
        close = (a == b) | (np.isnan(a) & np.isnan(b))
        if atol > 0:
            close |= np.abs(a - b) <= atol
    same &= np.where(a_null | b_null, a_null & b_null, close)
    equal[rows[np.repeat(np.arange(rows.size), lens)[~same]]] = False
    return equal


def terms_equal(a: Any, b: Any, atol: float) -> bool:
    """One row of :func:`_terms_rows_equal`: ``(name, value)`` lists, or ``None``."""
    if a is None or b is None:
        return a is None and b is None
    if [k for k, _ in a] != [k for k, _ in b]:
        return False
    for (_, x), (_, y) in zip(a, b, strict=True):
        if x is None or y is None:
            if x is None and y is None:
                continue
            return False
        if x == y or (x != x and y != y):
            continue
        if atol > 0 and abs(x - y) <= atol:
            continue
        return False
    return True
