"""The findings registry: every code ``check`` reports, with its severity, meaning and fix.

- :class:`FindingKind` is one code's entry; :data:`KINDS` lists them in order, and
  :data:`FINDING_CODES` their codes. Each code is also a constant (``TERMS_SUM_MISMATCH``, ...).
- :func:`kind_of` finds the entry of a code (``recorder_note:<code>`` is the ``recorder_note``
  family); :func:`ignored_codes` and :func:`is_ignored` validate and apply ``ignore``.

This is the single source of ``docs/findings.md``, which ``python -m episode_audit.check.docs``
writes; a test fails when the two differ.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final, Literal

from ..errors import ConfigurationError

__all__ = [
    "ACTION_OUT_OF_SPACE",
    "ACTION_SPACE_UNCHECKED",
    "ERROR_EPISODE",
    "EVIDENCE_DAMAGED",
    "FILE_RECOVERED",
    "FILE_UNFINISHED",
    "FILE_UNREADABLE",
    "FINDING_CODES",
    "FORMAT_VERSION",
    "INCOMPLETE_EPISODE",
    "INFO_KEYS_CHANGED",
    "KINDS",
    "LENGTH_MISMATCH",
    "MISSING_ENV_SPEC",
    "MISSING_TERMS",
    "NONFINITE_REWARD",
    "NONFINITE_TERM",
    "NOT_REPLAYABLE",
    "REWARDS_CHANGED",
    "OBSERVATION_OUT_OF_SPACE",
    "OBSERVATION_SPACE_UNCHECKED",
    "RECORDER_NOTE",
    "RECORDER_TROUBLE",
    "RUN_END_DAMAGED",
    "SEVERITY",
    "SEVERITY_RANK",
    "STEP_AFTER_END",
    "SUMMARY_DAMAGED",
    "TERMINATED_AND_TRUNCATED",
    "TERMS_KEYS_CHANGED",
    "TERMS_SUM_MISMATCH",
    "UNLABELED_FAILURE",
    "FindingKind",
    "Severity",
    "ignored_codes",
    "is_ignored",
    "kind_of",
]

Severity = Literal["error", "warning", "note"]
SEVERITY_RANK: Final[dict[str, int]] = {"error": 0, "warning": 1, "note": 2}
"""Severities, most severe first (findings of one location are ordered by it)."""

TERMS_SUM_MISMATCH = "terms_sum_mismatch"
MISSING_TERMS = "missing_terms"
NONFINITE_REWARD = "nonfinite_reward"
NONFINITE_TERM = "nonfinite_term"
OBSERVATION_OUT_OF_SPACE = "observation_out_of_space"
ACTION_OUT_OF_SPACE = "action_out_of_space"
OBSERVATION_SPACE_UNCHECKED = "observation_space_unchecked"
ACTION_SPACE_UNCHECKED = "action_space_unchecked"
STEP_AFTER_END = "step_after_end"
TERMINATED_AND_TRUNCATED = "terminated_and_truncated"
UNLABELED_FAILURE = "unlabeled_failure"
INCOMPLETE_EPISODE = "incomplete_episode"
ERROR_EPISODE = "error_episode"
LENGTH_MISMATCH = "length_mismatch"
RECORDER_NOTE = "recorder_note"
FILE_UNFINISHED = "file_unfinished"
RECORDER_TROUBLE = "recorder_trouble"
FILE_RECOVERED = "file_recovered"
SUMMARY_DAMAGED = "summary_damaged"
RUN_END_DAMAGED = "run_end_damaged"
EVIDENCE_DAMAGED = "evidence_damaged"
NOT_REPLAYABLE = "not_replayable"
REWARDS_CHANGED = "rewards_changed"
MISSING_ENV_SPEC = "missing_env_spec"
FORMAT_VERSION = "format_version"
FILE_UNREADABLE = "file_unreadable"
TERMS_KEYS_CHANGED = "terms_keys_changed"
INFO_KEYS_CHANGED = "info_keys_changed"


@dataclass(frozen=True)
class FindingKind:
    """One finding code: its severity, a one-line summary, what it means, why and how to fix.

    ``severity`` is the code's usual severity; ``severity_note`` says when it is another one.
    The texts are Markdown (they become ``docs/findings.md``).

    >>> kind_of("recorder_note:observation_cast").severity
    'warning'
    """

    code: str
    severity: Severity
    summary: str
    meaning: str
    why: str
    fix: str
    severity_note: str = ""


KINDS: Final[tuple[FindingKind, ...]] = (
    FindingKind(
        TERMS_SUM_MISMATCH,
        "error",
        "A step's reward is not the sum of its reward terms.",
        "A step's reward differs from the sum of its terms plus the declared constant terms by "
        "more than `atol + rtol * |reward|`. One finding per episode, naming the first such "
        "step, how many steps mismatch and the worst residual. Steps with a non-finite reward "
        "or term are reported as such instead.",
        "The terms explain the reward: a report's breakdown of a return by term is only true "
        "when they add up to what was paid. A term left out of `info`, a constant bonus not "
        "declared, or a wrapper between the env and the recorder that changes the reward but "
        "not its terms and that the recorder does not know (your own) all show here. A file "
        "whose layout names reward-changing wrappers under the recorder (`NormalizeReward`, "
        "any `RewardWrapper`: `rewards_changed`) holds their rewards and the env's terms: its "
        "terms are not checked against its rewards, and `rewards_changed` says so instead.",
        "Report every term the reward is summed from and declare the constant ones with "
        "`constant_terms=`; record below a wrapper that rescales the reward (wrap "
        "`RecordEvidence(env)` in it), or have the wrapper rescale the terms too; for float "
        "rounding, widen `--atol` / `--rtol`.",
    ),
    FindingKind(
        MISSING_TERMS,
        "warning",
        "Steps without reward terms.",
        "Steps whose row holds no reward terms. One finding per file, at the first such step, "
        "with their count and the file's terms source.",
        "Their rewards cannot be checked against terms, nor broken down by term in a report.",
        'Put the terms in `info["reward_terms"]` or tell the recorder where they are '
        "(`reward_terms=`). An env that has none needs nothing: the finding is a note.",
        "an error with `--require-terms` (`require_terms=True`); a note when the env reports "
        "no terms at all — the file was recorded with `reward_terms=None`, or with the default "
        '`"auto"` source and no step has terms (CartPole); a warning when the recording named '
        "where terms come from (a list of keys, a callable) or some steps have them",
    ),
    FindingKind(
        NONFINITE_REWARD,
        "error",
        "NaN or infinite rewards.",
        "Steps whose reward is NaN or infinite, including a reward that was not a number (the "
        "recorder keeps NaN for it and notes `reward_not_numeric`). One finding per episode, "
        "at its first such step, with the count.",
        "One non-finite reward makes every return, mean and interval it enters meaningless; "
        "it usually means the simulation or the reward computation broke down.",
        "Fix the reward computation in the env; `episode-audit show FILE -e EPISODE` shows the "
        "steps around the one named.",
    ),
    FindingKind(
        NONFINITE_TERM,
        "error",
        "NaN or infinite reward terms.",
        "Steps with a NaN or infinite reward term, including a term that was not a number (the "
        "recorder keeps NaN for it and notes `term_not_numeric`). One finding per episode, "
        "naming the first such step and term, with the count.",
        "The term breakdown of every return it enters is meaningless, and the step's reward "
        "cannot be checked against its terms.",
        "Fix the term's computation in the env (the finding names the term).",
    ),
    FindingKind(
        OBSERVATION_OUT_OF_SPACE,
        "error",
        "Observations outside the observation space.",
        "Observations the env returned that its observation space does not contain. One "
        "finding per episode, with the first such value and the count; a reset observation has "
        "no step.",
        "A policy is trained on inputs the space says cannot happen: normalisation, clipping "
        "and anything else built from the space is wrong for them.",
        "Fix the env, or declare the space it really has (e.g. a `Box` with wider bounds).",
    ),
    FindingKind(
        ACTION_OUT_OF_SPACE,
        "error",
        "Actions outside the action space.",
        "Actions the env was stepped with that its action space does not contain. One finding "
        "per episode, with the first such value and the count.",
        "The env ran on actions it does not define: it may clip them, wrap them or fail "
        "silently, and the policy learns from that.",
        "Keep the policy's actions in the space (clip them, e.g. with "
        "`gymnasium.wrappers.ClipAction`), or declare the space the env really accepts.",
    ),
    FindingKind(
        OBSERVATION_SPACE_UNCHECKED,
        "note",
        "Observations were not checked against their space.",
        "The observation space cannot be rebuilt from the file (a space the format does not "
        "describe, or a description that does not match the column), or checking the "
        "observations against it failed; the message says which.",
        "`observation_out_of_space` cannot be found in this file.",
        "Nothing to fix in the file. Record with one of Gymnasium's own spaces when the check "
        "matters.",
    ),
    FindingKind(
        ACTION_SPACE_UNCHECKED,
        "note",
        "Actions were not checked against their space.",
        "The same as `observation_space_unchecked`, for the action space.",
        "`action_out_of_space` cannot be found in this file.",
        "Nothing to fix in the file. Record with one of Gymnasium's own spaces when the check "
        "matters.",
    ),
    FindingKind(
        STEP_AFTER_END,
        "error",
        "Steps recorded after their episode ended.",
        "Rows of an episode after the row that carries its outcome, or rows the recorder "
        "noted as stepped after the episode had ended. One finding per episode, at the first "
        "such step, with the count.",
        "The loop kept stepping an ended episode without a reset: what the env does then is "
        "undefined, and those steps belong to no episode (`replay` leaves them out, so the "
        "later episodes of an env that keeps state across steps cannot be verified: `replay` "
        "calls those that differ not replayable).",
        "Call `reset()` once `terminated` or `truncated` is true (also after the env raised). "
        "An `Autoreset` wrapper deeper under the recorder resets the env inside a step the "
        "recorder cannot see (the message names it): put it over the recorder, or right under "
        "it, where its resets are recorded as episodes.",
    ),
    FindingKind(
        TERMINATED_AND_TRUNCATED,
        "note",
        "Episodes that ended with both flags set.",
        "Episodes that ended with both `terminated` and `truncated` set; their outcome is the "
        "task ending (success or failure), and the truncation reason is kept beside it. One "
        "finding per file, listing the episodes.",
        "Gymnasium allows it, but a time limit that coincides with task endings shifts "
        "episodes from the truncation rate to the success or failure rate.",
        "Nothing, when that is what the env means.",
    ),
    FindingKind(
        UNLABELED_FAILURE,
        "warning",
        "Failures without a label.",
        "Episodes that terminated without success and without a failure label. One finding per "
        "file, with how many of the file's failures, listing the episodes.",
        "A failure rate without reasons cannot tell a fall from a collision from a hacked "
        "reward: `report` counts these failures under `unlabeled`.",
        'Put a label in `info["failure"]` on the terminating step, or read it with '
        "`EndingRules(failure_fn=...)`. An env that labels no failure needs nothing: the "
        "finding is a note; but where it reports no success either, every episode it ends "
        "counts as a failure — where an ending can be a success (a goal reached), declare it "
        "with `EndingRules(success_fn=...)`.",
        "a note when the env labels no failure of the file and the recording named no label "
        "source (no `failure_fn`, the default `failure_key`): CartPole, Hopper; a warning "
        "when another failure of the file has a label, or the recording named a source",
    ),
    FindingKind(
        INCOMPLETE_EPISODE,
        "warning",
        "Episodes that did not end.",
        "Episodes whose recording stopped before they ended: a `reset()` before the end, the "
        "torn end of a file, an end record the recorder dropped (a full disk: "
        "`recorder_trouble` says what it dropped), or the recorder's `close()` (the run "
        "stopped mid-episode). One finding per file for the first three, listing the "
        "episodes, and one for the last. An "
        "episode that was reset and never stepped (a vector env's autoreset after the last "
        "episode a loop ran, a `reset()` followed by `close()`) is *unstarted*: not reported, "
        "and `report` leaves it out.",
        "Their outcome is unknown: `report` counts them apart, outside the ended episodes its "
        "rates are over. A training run that stops mid-episode always leaves one per env; an "
        "episode cut by a reset or a crash may hide an ending that never got recorded.",
        "Nothing for the episodes `close()` cut; let an episode end before resetting. A torn "
        "file's lost steps, and what the recorder dropped, cannot be brought back.",
        "a note for the episodes `close()` cut: the last episode of each stream (env, "
        "sub-env or agent, in the last game of a PettingZoo file) of a file whose end record "
        "the recorder wrote",
    ),
    FindingKind(
        ERROR_EPISODE,
        "error",
        "The environment raised during the episode.",
        "The env raised an exception in `step` or `reset`; the recorder kept the episode with "
        "outcome `error` and re-raised it. One finding per episode, with the exception's type "
        "and message and the step.",
        "The episode ended in a crash, not in a task outcome. A step that raised is no row; a "
        "single env's file keeps its action, and `replay` steps it again after the steps "
        "before it, expecting the same exception (another, or none, makes the episode not "
        "replayable). Where it cannot (a vector or PettingZoo file, a reset that raised), the "
        "later episodes of an env that keeps state cannot be verified (`replay` calls those "
        "that differ not replayable).",
        "Fix the env (the message names the exception and the step).",
    ),
    FindingKind(
        LENGTH_MISMATCH,
        "error",
        "An episode record disagrees with the file's step rows.",
        "An episode record's length differs from the number of its step rows up to its "
        "outcome row. One finding per episode.",
        "The file contradicts itself: the episode's step rows are not the ones its record counted.",
        "Re-record, or use an intact copy of the file; a recovered file says what it lost in "
        "`evidence_damaged`.",
    ),
    FindingKind(
        RECORDER_NOTE,
        "warning",
        "The recorder noted what it could not store as is.",
        "Steps or resets the recorder annotated with the note `<code>` (e.g. "
        "`observation_invalid`, `term_not_numeric`, `info_unserializable`, "
        "`reward_not_numeric`). One finding per episode and code; a note with the same message "
        "in more than five episodes (e.g. every autoreset of a vector env) is one finding "
        "naming them. `env_raised` is a PettingZoo AEC env that raised after every "
        "agent-episode had ended. The notes on what a replay needs (`seed_out_of_range`, "
        "`rng_state_unavailable`, `options_unserializable`, `state_unavailable`) are left out "
        "at the reset of an unstarted episode (reset, never stepped): nothing of it to replay.",
        "The recorder keeps what the env returned and never raises into the training loop; "
        "the note is how it says the env returned something malformed.",
        "Fix what the note names in the env (docs/cli.md lists what the env did for each "
        "note); `--ignore recorder_note:<code>` leaves one code out, `--ignore recorder_note` "
        "all of them.",
        "an error for `recorder_note:env_raised`",
    ),
    FindingKind(
        FILE_UNFINISHED,
        "warning",
        "The writer did not finish the file.",
        "The file has no run-end record: the recorder was killed or crashed, or is still "
        "recording. The message says which: a live recorder holds the file's lock, and is "
        "named (its pid); for a torn file it says what the reader dropped, or that the file "
        "holds no complete chunk at all.",
        "Steps after the recorder's last flush are in no file, and the episodes it was "
        "recording are incomplete.",
        "Close the recorder (`with RecordEvidence(...)`, or `close()`); a live one, wait for "
        "it. `episode-audit recover` writes a finished copy of a torn file.",
        "an error when no recorder is writing the file and it holds no complete chunk: its "
        "evidence is gone (no episode, reset or step to check), and a gate on `check` must "
        "not pass it",
    ),
    FindingKind(
        RECORDER_TROUBLE,
        "error",
        "The recorder failed inside itself while recording.",
        "The recorder failed inside itself (it warned once and never raised into the loop); "
        "the run-end record counts the failures and keeps the first. When it had to drop "
        "flushes the OS refused (a disk full for longer than it could hold them), the run-end "
        "record also counts the step rows, reset rows and episode records dropped, and the "
        "message says how many.",
        "The evidence may miss what the recorder was recording when it failed. Dropped rows "
        "and records are gone: the file's episodes, steps and outcomes are not the whole run, "
        "and the episodes whose end was dropped read as incomplete.",
        "Read the first failure in the message (e.g. a full disk, or a bug to report with the "
        "file) and re-record once it is fixed: for a full disk, free space (or record "
        "elsewhere) and record the run again.",
    ),
    FindingKind(
        FILE_RECOVERED,
        "warning",
        "The file was rewritten by `episode-audit recover`.",
        "The file was rewritten by `episode-audit recover` from a torn or damaged file; the "
        "message says what was dropped.",
        "The original lost what the message says.",
        "Nothing to fix in this file; `--ignore file_recovered` once it is known.",
        "an error when the recovered file holds no episode and no reset: the original held no "
        "complete chunk, its evidence is gone, and a gate on `check` must not pass it",
    ),
    FindingKind(
        SUMMARY_DAMAGED,
        "warning",
        "The summary at the end of a finished file is damaged.",
        "A finished file's summary section (MCAP's index) does not match the footer's CRC, or "
        "the footer or closing magic is garbled. The file was read by scanning its data "
        "section, which holds all the evidence.",
        "Nothing was lost, but other MCAP tools, which trust the summary, may fail on the "
        "file or read it wrong.",
        "`episode-audit recover FILE --out COPY` writes a copy with a new summary.",
    ),
    FindingKind(
        RUN_END_DAMAGED,
        "warning",
        "The run-end record of a finished file is garbled.",
        "A finished file's run-end record (which its sound summary locates) is garbled: every "
        "chunk is there, but the record's status and counts are lost.",
        "What the record said is lost: how the recording ended, its counts, and the "
        "recorder's failures that `recorder_trouble` reports.",
        "`episode-audit recover FILE --out COPY` writes a copy with a new run-end record.",
    ),
    FindingKind(
        EVIDENCE_DAMAGED,
        "error",
        "Episodes lost evidence to damaged chunks.",
        "`recover` skipped damaged chunks of the original file; the message says how many "
        "stretches and which episodes lost part or all of their evidence. One finding per file.",
        "Those episodes' records, steps and outcomes are not the whole run; `replay` marks "
        "them not replayable.",
        "Recover from an intact copy of the original if there is one; otherwise leave those "
        "episodes out of any conclusion.",
    ),
    FindingKind(
        NOT_REPLAYABLE,
        "warning",
        "Episodes that cannot be replayed.",
        "Episodes with neither a reset seed nor an RNG state, one finding per file listing up to "
        "five (an unstarted episode, reset and never stepped, is not one of them: there is nothing "
        "of it to replay); a vector file whose vector env had no sub-envs, so no episode can be "
        "replayed on its own; or, one finding per cause, state replay cannot restore: a recorded "
        "wrapper that keeps state across episodes (running statistics) without a state snapshot, "
        "or a vector wrapper the vector recorder wrapped; or a vector file whose sub-envs ran in "
        "`AsyncVectorEnv` / `SubprocVecEnv` workers under a frame-skipping wrapper, where the spec "
        "cannot tell whether its `TimeLimit`s sat over the frame skip or under it (replay needs "
        "`--env-factory` there).",
        "`replay` cannot re-run them, so nothing confirms that their steps are what the env does.",
        "Reset before stepping, with a seed (`env.reset(seed=...)`) where you can; put the "
        "recorder innermost, directly around the env (or the vector env), under wrappers that "
        "keep state (a vector recorder cannot sit inside its sub-envs' wrappers: wrap each "
        "sub-env in `ResetRngInfo`, outermost, which snapshots those with a state adapter); "
        "record sub-envs under a frame skip with `SyncVectorEnv` / `DummyVecEnv`, "
        "or replay such a file with `--env-factory` building the sub-env as recorded.",
    ),
    FindingKind(
        REWARDS_CHANGED,
        "note",
        "The recorded rewards are a wrapper's, not the env's.",
        "The recorder sat over a wrapper that changes the reward (`NormalizeReward`, "
        "`TransformReward`, `ClipReward`, any `RewardWrapper`, SB3's `VecNormalize` with "
        "`norm_reward`), so every recorded reward, and every return `report` and `compare` "
        "read, is that wrapper's, while the reward terms in the info are still the env's: the "
        "terms are not checked against these rewards (no `terms_sum_mismatch`), and where "
        "steps have terms the message says how many were not checked. One finding per file, "
        "naming the wrappers. A note, not a warning: recording what the agent saw can be the "
        "point.",
        "A normalised return is on another scale than the env's (a CartPole return no longer "
        "equals its length) and drifts with the wrapper's running statistics: rates are "
        "unaffected, but returns, return gates and `compare`'s return verdicts are not the "
        "task's. `report` and `compare` say how many files' returns are a wrapper's; `compare` "
        "does not compare returns whose sides' wrappers differ. Nothing confirms that the "
        "terms add up to what the env paid.",
        "Put the recorder beneath the reward wrapper, directly around the env "
        "(`NormalizeReward(RecordEvidence(env, path))`); the training loop still sees the "
        "wrapper's rewards, and the file holds the env's, checked against their terms.",
    ),
    FindingKind(
        MISSING_ENV_SPEC,
        "warning",
        "No environment spec to rebuild the env.",
        "The file has no environment spec (the env was not made with `gym.make`; the message "
        "gives the recorder's notes on why), or one with placeholders for arguments JSON "
        "cannot hold (a function given to a wrapper: `TransformReward(env, lambda r: ...)`).",
        "`replay` cannot build the env from the file alone.",
        "Make the env with `gym.make` from a registered id, or give `replay` an env factory "
        "(`--env-factory MODULE:CALLABLE`).",
    ),
    FindingKind(
        FORMAT_VERSION,
        "note",
        "Written with an older format version.",
        "The file was written with an older version of the evidence format than the current one.",
        "Nothing is wrong (later readers keep reading older files); worth knowing when the "
        "file lacks something newer recordings have.",
        "Nothing to fix; re-record to use the current format.",
    ),
    FindingKind(
        FILE_UNREADABLE,
        "error",
        "An input that could not be read at all.",
        "An input that is not readable evidence (no read permission, not MCAP, not evidence, "
        "torn before its run metadata, a newer format, damaged chunks). Reported by the CLI "
        "and by `check(..., keep_going=True)`, so a JSON result never reads as `ok` over it; "
        "the CLI also names it on stderr and exits 2.",
        "Nothing in the file was checked.",
        "The message says why. `episode-audit recover` copies what is intact out of a file "
        "with damaged chunks.",
    ),
    FindingKind(
        TERMS_KEYS_CHANGED,
        "note",
        "Reward-term names changed within an episode.",
        "The set of reward-term names changed from one step to the next within an episode. "
        "One finding per file: how many episodes, the first change and the names added and "
        "removed. Steps without terms are not compared.",
        "Steps of one episode break their rewards down differently: by design for a bonus or "
        "penalty paid only on some steps, a bug when the env forgets to report a term.",
        "Nothing, when it is by design; otherwise report every term on every step (a zero "
        "when it does not apply).",
    ),
    FindingKind(
        INFO_KEYS_CHANGED,
        "note",
        "Kept info keys changed within an episode.",
        "The same as `terms_keys_changed`, for the info keys the recorder kept (`info_keys=`); "
        "only steps with kept info are compared.",
        "Code that reads the kept info of every step finds keys missing on some.",
        "Nothing, when it is by design; otherwise give the env's info the same keys on every step.",
    ),
)
"""Every finding code's entry, in the order of ``docs/findings.md``."""

FINDING_CODES: Final[tuple[str, ...]] = tuple(kind.code for kind in KINDS)
"""Every finding code, in the order of :data:`KINDS`.

``recorder_note`` stands for the whole family ``recorder_note:<code>``, whose codes are the
recorder's own (open-ended: a file may hold notes of a newer or another writer).
"""

_BY_CODE: Final[dict[str, FindingKind]] = {kind.code: kind for kind in KINDS}
SEVERITY: Final[dict[str, Severity]] = {kind.code: kind.severity for kind in KINDS}
"""The usual severity of each code (see :attr:`FindingKind.severity_note`)."""


def kind_of(code: str) -> FindingKind:
    """The entry of ``code``; ``recorder_note:<code>`` is the ``recorder_note`` entry.

    >>> kind_of("terms_sum_mismatch").summary
    "A step's reward is not the sum of its reward terms."
    """
    family, sep, note = code.partition(":")
    kind = _BY_CODE.get(RECORDER_NOTE if sep and family == RECORDER_NOTE and note else code)
    if kind is None:
        raise KeyError(code)
    return kind


def ignored_codes(codes: Iterable[str], *, option: str = "ignore") -> frozenset[str]:
    """Validate finding codes to ignore; return them as a set for :func:`is_ignored`.

    A code is one of :data:`FINDING_CODES`; ``recorder_note`` stands for every recorder note,
    ``recorder_note:<code>`` for one of them. An unknown code raises
    :class:`~episode_audit.errors.ConfigurationError` naming it (under ``option``) and listing
    the known ones, so a misspelt code does not silently ignore nothing.

    >>> sorted(ignored_codes(["missing_terms", "recorder_note:observation_cast"]))
    ['missing_terms', 'recorder_note:observation_cast']
    >>> ignored_codes(["missing_term"])  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    episode_audit.errors.ConfigurationError: ignore: unknown finding code 'missing_term'; \
known codes: terms_sum_mismatch, missing_terms, ...
    """
    wanted = [codes] if isinstance(codes, str) else list(codes)
    for code in wanted:
        family, sep, note = code.partition(":")
        if code in _BY_CODE or (sep and family == RECORDER_NOTE and note):
            continue
        raise ConfigurationError(
            f"{option}: unknown finding code {code!r}; known codes: {', '.join(FINDING_CODES)} "
            f"({RECORDER_NOTE} for every recorder note, {RECORDER_NOTE}:<code> for one)"
        )
    return frozenset(wanted)


def ignored_by(code: str, ignored: frozenset[str]) -> str | None:
    """The code among ``ignored`` that leaves out a finding's ``code``, or ``None``.

    >>> ignored_by("recorder_note:observation_cast", frozenset({"recorder_note"}))
    'recorder_note'
    >>> print(ignored_by("missing_terms", frozenset({"recorder_note"})))
    None
    """
    if code in ignored:
        return code
    if RECORDER_NOTE in ignored and code.startswith(RECORDER_NOTE + ":"):
        return RECORDER_NOTE
    return None


def is_ignored(code: str, ignored: frozenset[str]) -> bool:
    """Whether a finding's ``code`` is among ``ignored`` (from :func:`ignored_codes`).

    >>> is_ignored("recorder_note:observation_cast", frozenset({"recorder_note"}))
    True
    """
    if not ignored:
        return False
    return code in ignored or (code.startswith(RECORDER_NOTE + ":") and RECORDER_NOTE in ignored)
