"""CartPole policies for ``record_episodes(policy="tests.support.cartpole:NAME")``."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


def balance(env: Any, seed: int) -> Callable[[Any], int]:
    """Push the cart the way the pole leans (and is moving): it stays up to the time limit."""
    return lambda obs: int(obs[2] + 0.5 * obs[3] > 0)


def always_left(env: Any, seed: int) -> Callable[[Any], int]:
    """Push the cart left at every step: the pole falls within a dozen steps."""
    return lambda obs: 0
