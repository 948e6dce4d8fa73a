"""An SB3 ``VecEnv`` step as Gymnasium's ``SAME_STEP`` vector step, and its autoreset strategy.

- :class:`StepReader` — SB3's ``(obs, rewards, dones, infos)`` read as Gymnasium's five values:
  ``truncated`` from ``infos[i]["TimeLimit.truncated"]``, ``terminated`` the other endings; an
  ending sub-env's info holds ``final_obs`` (``terminal_observation``), ``final_info`` (its step
  info) and its reset info (SB3's ``reset_infos[i]``), as ``SameStep`` reads them.
- :class:`Sb3SameStep` — ``SameStep`` that also restores a ``truncated`` SB3 folded away.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from ..vector.infos import EMPTY
from ..vector.modes import SameStep
from ..vector.rng import without_own_keys

__all__ = ["TERMINAL_OBSERVATION", "TIME_LIMIT_TRUNCATED", "Sb3SameStep", "StepReader"]

TIME_LIMIT_TRUNCATED = "TimeLimit.truncated"
"""SB3's info key: the sub-env's ``truncated and not terminated`` (set on every step)."""
TERMINAL_OBSERVATION = "terminal_observation"
"""SB3's info key: the last observation of an episode the VecEnv has just reset."""
_ADDED = (TIME_LIMIT_TRUNCATED, TERMINAL_OBSERVATION)
_BOOL = np.dtype(np.bool_)


def _own(info: Any) -> Any:
    """A sub-env's info without the keys SB3 added (a value that is no dict: as it is)."""
    if type(info) is not dict and not isinstance(info, Mapping):
        return info
    if len(info) == 1 and TIME_LIMIT_TRUNCATED in info:
        return EMPTY
    if type(info) is dict and TERMINAL_OBSERVATION not in info:  # (SB3's one key, most steps)
        own = info.copy()
        own.pop(TIME_LIMIT_TRUNCATED, None)
        return own
    return {k: v for k, v in info.items() if k not in _ADDED}


class StepReader:
    """Read SB3 VecEnv steps as Gymnasium ``SAME_STEP`` vector steps.

    ``reset_infos`` gives the VecEnv's ``reset_infos`` after the step (the reset infos of the
    sub-envs it reset inside the step). ``installed``: per sub-env, whether the recorder put
    its :class:`~..vector.rng.ResetRngInfo` there (``None``: on none); a reset info of such a
    sub-env loses that wrapper's keys once read, in the VecEnv's list, which the loop may read.
    """

    def __init__(
        self,
        n: int,
        reset_infos: Callable[[], Sequence[Any]],
        installed: Sequence[bool] | None = None,
    ) -> None:
        self._n = n
        self._reset_infos = reset_infos
        self._installed = installed
        self._false = np.zeros(n, dtype=np.bool_)
        self._false.flags.writeable = False
        self._plain = [EMPTY] * n
        # what SB3 >= 2's VecEnvs give on a step without an ending (compared in one go)
        self._sb3_plain = [{TIME_LIMIT_TRUNCATED: False} for _ in range(n)]

    def read(self, result: tuple[Any, Any, Any, Any]) -> tuple[Any, Any, Any, Any, Any]:
        """``(obs, rewards, terminated, truncated, infos)`` of an SB3 ``step_wait()`` result."""
        obs, rewards, dones, infos = result
        n = self._n
        if type(dones) is not np.ndarray or dones.dtype is not _BOOL or dones.shape != (n,):
            dones = np.asarray(dones).astype(np.bool_).reshape(n)
        if not isinstance(infos, (list, tuple)) or len(infos) != n:
            return obs, rewards, dones, self._false, infos  # handed on as it is (noted)
        ended = dones.tolist()
        if True not in ended and infos == self._sb3_plain:
            return obs, rewards, self._false, self._false, self._plain
        subs: list[Any] = self._plain
        plain = self._sb3_plain[0]
        for i, info in enumerate(infos):
            if type(info) is dict and info == plain:
                continue
            own = _own(info)
            if own is not EMPTY:
                if subs is self._plain:
                    subs = list(subs)
                subs[i] = own
        if True not in ended:
            return obs, rewards, self._false, self._false, subs
        if subs is self._plain:
            subs = list(subs)
        terminated = dones.copy()
        truncated = np.zeros(n, dtype=np.bool_)
        reset_infos = self._reset_infos()
        for i, done in enumerate(ended):
            info = infos[i]
            if not done or not isinstance(info, Mapping):
                continue
            if info.get(TIME_LIMIT_TRUNCATED):
                terminated[i], truncated[i] = False, True
            reset_info = reset_infos[i] if i < len(reset_infos) else EMPTY
            ending = {**reset_info, "final_info": subs[i]}
            if self._installed is not None and type(reset_infos) is list and self._installed[i]:
                reset_infos[i] = without_own_keys(reset_info)
            if TERMINAL_OBSERVATION in info:
                ending["final_obs"] = info[TERMINAL_OBSERVATION]
            subs[i] = ending
        return obs, rewards, terminated, truncated, subs


class Sb3SameStep(SameStep):
    """``SAME_STEP`` as SB3 autoresets: also restores ``truncated`` on a time-limit ending.

    SB3 keeps ``truncated and not terminated`` only: a step that both terminates and reaches
    the sub-env's step limit (where ``TimeLimit`` sets ``truncated`` as well) arrives as
    terminated alone. With the limit known, ``truncated`` is set again on such a step, as the
    sub-env returned it; ``limits`` are the sub-envs' step limits (``None``: unknown).
    """

    limits: Sequence[int | None] = ()

    def ending_flags(self, i: int, terminated: Any, truncated: Any, step: int) -> tuple[Any, Any]:
        """``truncated`` set again when the ending step ``step`` reached the sub-env's limit."""
        limit = self.limits[i] if i < len(self.limits) else None
        if terminated and not truncated and limit is not None and step + 1 >= limit:
            return terminated, True
        return terminated, truncated
