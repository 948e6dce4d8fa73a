"""``DeepAutoreset-v0``: CartPole with an ``Autoreset`` under a reward wrapper.

A recorder over it warns (a :class:`~episode_audit.errors.RecorderWarning`: the ``Autoreset``
is not right under it); making it also gives a plain ``UserWarning``, as another library's.
"""

from __future__ import annotations

import warnings
from typing import Any

import gymnasium as gym
from gymnasium.wrappers import Autoreset, ClipReward

DEEP_AUTORESET = "DeepAutoreset-v0"
PLAIN_WARNING = "DeepAutoreset-v0: a warning of another library's"


def _make() -> gym.Env[Any, Any]:
    warnings.warn(PLAIN_WARNING, UserWarning, stacklevel=1)
    return ClipReward(Autoreset(gym.make("CartPole-v1")), -1, 1)


gym.register(DEEP_AUTORESET, entry_point=_make, max_episode_steps=50)
