"""AEC turn accounting (:class:`AECTurns`), shared by the AEC recorder and replay.

Row ``k`` of agent X is X's ``k``-th action; its reward is the sum of ``env.rewards[X]`` over
every ``step()`` until X's next turn, its observation, flags and info X's at that turn (never
``last()``'s cumulative reward). The full rules: ``docs/format.md``, "PettingZoo files".
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

from ...format.columns import number
from ..notes import note

__all__ = ["AECTurns", "ResetFn", "RowFn"]

RowFn = Callable[[str, Any, tuple[Any, float, bool, bool, Any], list[str]], None]
ResetFn = Callable[[str, Any, Any], None]


def _float(value: Any, notes: list[str], agent: str) -> float:
    try:
        return number(value)
    except Exception:
        notes.append(note("reward_not_numeric", f"agent {agent!r}: reward {value!r}"))
        return math.nan


class AECTurns:
    """Per-agent turn accounting of an AEC env (see the module docstring).

    Call :meth:`begin` after ``reset()``, :meth:`turn` just before each ``step(action)``,
    :meth:`stepped` just after it (or :meth:`failed` if it raised) and :meth:`finish` when the
    game is cut (next reset, close). ``on_reset(agent, obs, info)`` is called at an agent's first
    turn; ``on_row(agent, action, (obs, reward, terminated, truncated, info), notes)`` when one of
    its rows closes. The recorder and the replay share this class, so they account turns
    identically.
    """

    def __init__(self, env: Any, on_reset: ResetFn, on_row: RowFn) -> None:
        self.env = env
        self.on_reset = on_reset
        self.on_row = on_row
        self.pending: dict[str, list[Any]] = {}  # agent -> [action, reward, notes]
        self.early: dict[str, float] = {}  # rewards received before the first action
        self.started: set[str] = set()
        self.expected: list[str] = []
        self.acting: str | None = None  # whose row the last turn() opened

    def begin(self, agents: Sequence[str]) -> None:
        """A new game began with ``agents``."""
        self.pending = {}
        self.early = {}
        self.started = set()
        self.expected = list(agents)
        self.acting = None

    def _start(self, agent: str) -> None:
        if agent in self.started:
            return
        self.started.add(agent)
        env = self.env
        live = agent in env.agents
        obs = env.observe(agent) if live else None
        self.on_reset(agent, obs, env.infos.get(agent, {}) if live else {})

    def _close(self, agent: str) -> None:
        row = self.pending.pop(agent, None)
        if row is None:
            return
        action, reward, notes = row
        env = self.env
        if agent in env.agents:
            obs = env.observe(agent)
            term = env.terminations.get(agent, False)
            trunc = env.truncations.get(agent, False)
            info = env.infos.get(agent, {})
        else:
            obs, term, trunc, info = None, False, False, {}
        self.on_row(agent, action, (obs, reward, term, trunc, info), notes)

    def arrive(self) -> str:
        """``agent_selection``'s turn has come: begin it (reset row), close its open row.

        What :meth:`turn` does before the action; the replay calls it alone where the recorded
        actions run out. Returns the agent.
        """
        agent: str = self.env.agent_selection
        self._start(agent)
        self._close(agent)
        return agent

    def turn(self, action: Any) -> bool:
        """Account for ``step(action)`` about to run; return whether it is a dead step."""
        self.acting = None
        env = self.env
        agent = self.arrive()
        dead = bool(env.terminations.get(agent, False) or env.truncations.get(agent, False))
        if not dead:
            notes: list[str] = []
            reward = self.early.pop(agent, 0.0)
            if reward:
                notes.append(
                    note(
                        "reward_before_first_turn",
                        f"{reward!r} received before agent {agent!r} first acted; "
                        "added to its first step",
                    )
                )
            self.pending[agent] = [action, reward, notes]
            self.acting = agent
        return dead

    def failed(self) -> None:
        """The ``step()`` accounted by the last :meth:`turn` raised: the game's turns are over.

        Its action is no row (as a Gymnasium step that raises). The other open rows — actions
        whose step did complete — are closed with the env's state now; agents that had no turn
        get no reset row, and a later :meth:`finish` does nothing.
        """
        if self.acting is not None:
            self.pending.pop(self.acting, None)
        self.acting = None
        self.expected = []
        try:
            for agent in list(self.pending):
                self._close(agent)
        finally:
            self.pending = {}  # a row the env's state could not close is dropped, not kept

    def stepped(self) -> None:
        """Add the rewards the step just produced (``env.rewards``) to each agent's open row."""
        for agent, value in self.env.rewards.items():
            row = self.pending.get(agent)
            if row is not None:
                row[1] += _float(value, row[2], agent)
            elif agent not in self.started and value:
                self.early[agent] = self.early.get(agent, 0.0) + _float(value, [], agent)

    def finish(self) -> None:
        """Close every open row and start every agent still without a reset row."""
        for agent in self.expected:
            self._start(agent)
        for agent in list(self.pending):
            self._close(agent)
