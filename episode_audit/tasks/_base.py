"""Shared machinery of the reference MuJoCo tasks (private).

- :class:`MujocoTaskEnv` -- a :class:`gymnasium.Env` over a small MJCF model: loading, seeding,
  stepping with a per-substep hook, the reward-term bookkeeping and ``rgb_array`` rendering.
- :func:`quantize` -- rounds a reward term so sums of terms are exact in any order.
"""

from __future__ import annotations

import math
from importlib import resources
from typing import Any, ClassVar, SupportsFloat

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

__all__ = ["GAMMA", "MujocoTaskEnv", "quantize"]

GAMMA = 0.99
"""Discount of the potential-based shaping term ``GAMMA * phi(s') - phi(s)``."""

_QUANTUM = 2.0**-32
"""Reward terms are multiples of this, so any summation order of a few of them is exact."""

Obs = NDArray[np.float64]
Act = NDArray[np.float32]


def quantize(value: float) -> float:
    """Round ``value`` to a multiple of ``2**-32``.

    Terms of magnitude below ``2**20`` on this grid add without rounding error in float64, so
    ``sum(terms.values())`` is the same number whichever way it is summed (left to right,
    compensated, pairwise). Non-finite values pass through unchanged.

    >>> quantize(0.1) == 0.1
    False
    >>> abs(quantize(0.1) - 0.1) < 1e-9
    True
    >>> quantize(0.1) + quantize(0.2) - quantize(0.2) == quantize(0.1)
    True
    """
    if not math.isfinite(value):
        return value
    return round(value / _QUANTUM) * _QUANTUM


class MujocoTaskEnv(gym.Env[Obs, Act]):
    """Base class of the reference tasks: a MuJoCo model stepped ``frame_skip`` times per action.

    Subclasses set the class attributes, implement the ``_``-prefixed hooks, and get:

    - ``reset(seed=...)`` deterministic through ``self.np_random`` (the only source of noise);
    - ``step`` returning ``info == {"reward_terms": ..., "success": ..., "failure": ...}`` where the
      reward is ``sum(info["reward_terms"].values())`` exactly;
    - ``render()`` for ``render_mode="rgb_array"`` from the model's ``overview`` camera, frames of
      ``width`` x ``height`` pixels (at most 640 x 480).

    A step that meets a failure predicate is a failure even if the success predicate also holds.

    Terminal states have potential 0 (``phi(s_T) = 0``), as potential-based shaping requires for
    episodic tasks, so the shaping terms of an episode telescope to ``-phi(s_0)`` plus the
    discounting residue and cannot change which policy is optimal.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}  # noqa: RUF012 (Gymnasium API)

    task_id: ClassVar[str]
    """The id the task is registered under, used by :mod:`episode_audit.tasks.policies`."""
    model_file: ClassVar[str]
    """File name of the MJCF model in ``episode_audit/tasks/assets``."""
    frame_skip: ClassVar[int] = 4
    """Physics steps per action (the models use ``timestep = 0.01``, so one action is 40 ms)."""
    action_dim: ClassVar[int]
    obs_low: ClassVar[tuple[float, ...]]
    """Lower bounds of the observation, one per entry (finite and generous)."""
    obs_high: ClassVar[tuple[float, ...]]
    success_bonus: ClassVar[float] = 10.0
    failure_penalty: ClassVar[float] = 5.0
    ctrl_cost_weight: ClassVar[float] = 0.01
    proxy_weight: ClassVar[float] = 1.0
    """Weight of the ``progress_velocity`` term of the proxy reward."""
    proxy_speed: ClassVar[float] = 1.0
    """The proxy term is ``proxy_weight * (max(v, 0) / proxy_speed) ** 2`` per step."""
    substep_hook: ClassVar[bool] = False
    """Whether to call :meth:`_after_substep` after every physics substep."""

    def __init__(
        self,
        *,
        render_mode: str | None = None,
        proxy_reward: bool = False,
        width: int = 320,
        height: int = 240,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"Expect render_mode None or one of {self.metadata['render_modes']}, "
                f"actually: {render_mode!r}"
            )
        self.render_mode = render_mode
        self.proxy_reward = proxy_reward
        self.width = width
        self.height = height
        xml = (resources.files(__package__) / "assets" / self.model_file).read_text()
        self.model = mujoco.MjModel.from_xml_string(xml)
        max_width, max_height = self.model.vis.global_.offwidth, self.model.vis.global_.offheight
        if not (0 < width <= max_width and 0 < height <= max_height):
            raise ValueError(
                f"Expect 0 < width <= {max_width} and 0 < height <= {max_height}, "
                f"actually: width={width}, height={height}"
            )
        self.data = mujoco.MjData(self.model)
        self.dt = float(self.model.opt.timestep) * self.frame_skip
        """Seconds of simulated time per step (``render_fps`` is ``1 / dt``)."""
        self.action_space = spaces.Box(-1.0, 1.0, shape=(self.action_dim,), dtype=np.float32)
        self.observation_space = spaces.Box(
            np.array(self.obs_low, dtype=np.float64),
            np.array(self.obs_high, dtype=np.float64),
            dtype=np.float64,
        )
        self._renderer: Any = None
        self._potential = 0.0
        self._bind_views()
        self._q: list[float] = self._qpos.tolist()
        self._v: list[float] = self._qvel.tolist()

    def _bind_views(self) -> None:
        # Views into ``self.data``, valid for its lifetime; rebound after unpickling or deepcopy.
        self._qpos = self.data.qpos
        self._qvel = self.data.qvel
        self._sensordata = self.data.sensordata

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        for name in ("_qpos", "_qvel", "_sensordata", "_renderer"):
            state.pop(name, None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._renderer = None
        self._bind_views()

    # ------------------------------------------------------------------ hooks for subclasses
    # After each action the base class takes a snapshot of ``qpos``/``qvel`` as Python lists
    # (``self._q``, ``self._v``); the hooks below read it with plain float arithmetic, which is far
    # cheaper than numpy on a dozen scalars and keeps a step well under 100 microseconds.

    def _randomize(self) -> None:
        """Set ``self.data.qpos``/``qvel`` of a fresh episode, drawing noise from ``np_random``."""
        raise NotImplementedError

    def _reset_episode_state(self) -> None:
        """Clear per-episode bookkeeping (peak trackers, counters)."""

    def _after_substep(self) -> None:
        """Track peaks after every physics substep, when ``substep_hook`` is true."""

    def _observe(self) -> Obs:
        """Build the observation from the snapshot."""
        raise NotImplementedError

    def _potential_of_state(self) -> float:
        """Potential ``phi(s)`` of the snapshot state, for a non-terminal state."""
        raise NotImplementedError

    def _progress_speed(self) -> float:
        """Speed of the task coordinate toward its goal (the proxy reward pays for it)."""
        raise NotImplementedError

    def _outcome(self) -> tuple[bool, str | None]:
        """Return ``(success, failure_label)`` of the snapshot state; called once per step."""
        raise NotImplementedError

    def _ctrl_from_action(self, action: list[float]) -> list[float]:
        """Map the clipped action to ``data.ctrl`` (identity unless a subclass says otherwise)."""
        return action

    # ------------------------------------------------------------------ gymnasium API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Obs, dict[str, Any]]:
        """Reset to a noisy initial state drawn from ``self.np_random``; the info is empty."""
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        self._randomize()
        mujoco.mj_forward(self.model, self.data)
        self._snapshot()
        self._reset_episode_state()
        self._potential = self._potential_of_state()
        return self._observe(), {}

    def step(self, action: Act) -> tuple[Obs, SupportsFloat, bool, bool, dict[str, Any]]:
        """Apply ``action`` for ``frame_skip`` physics steps and evaluate the task predicates."""
        act = [min(1.0, max(-1.0, x)) for x in np.ravel(np.asarray(action, np.float64)).tolist()]
        if len(act) != self.action_dim:
            raise ValueError(f"Expect an action of shape ({self.action_dim},), actually: {act}")
        model, data = self.model, self.data
        data.ctrl[:] = self._ctrl_from_action(act)
        if self.substep_hook:
            for _ in range(self.frame_skip):
                mujoco.mj_step(model, data)
                self._after_substep()
        else:
            mujoco.mj_step(model, data, self.frame_skip)
        self._snapshot()
        success, failure = self._outcome()
        if failure is not None:
            success = False
        terminated = success or failure is not None
        ctrl_cost = -self.ctrl_cost_weight * sum(x * x for x in act)
        bonus = self.success_bonus if success else 0.0
        terms: dict[str, float]
        if self.proxy_reward:
            speed = max(self._progress_speed(), 0.0) / self.proxy_speed
            terms = {
                "progress_velocity": quantize(self.proxy_weight * speed * speed),
                "ctrl_cost": quantize(ctrl_cost),
                "success_bonus": bonus,
            }
        else:
            potential = 0.0 if terminated else self._potential_of_state()
            shaping = GAMMA * potential - self._potential
            self._potential = potential
            terms = {
                "shaping": quantize(shaping),
                "ctrl_cost": quantize(ctrl_cost),
                "failure_penalty": -self.failure_penalty if failure is not None else 0.0,
                "success_bonus": bonus,
            }
        reward = sum(terms.values())
        info = {"reward_terms": terms, "success": success, "failure": failure}
        return self._observe(), reward, terminated, False, info

    def render(self) -> NDArray[np.uint8] | None:
        """Return an RGB frame of the ``overview`` camera, or ``None`` without a render mode.

        Headless machines need ``MUJOCO_GL=egl`` (or ``osmesa``) set before ``mujoco`` is imported.
        """
        if self.render_mode is None:
            return None
        if self._renderer is None:
            try:
                self._renderer = mujoco.Renderer(self.model, self.height, self.width)
            except Exception as exc:  # mujoco raises FatalError or GL-specific errors
                raise RuntimeError(
                    "rgb_array rendering needs an OpenGL context; on a headless machine set "
                    "MUJOCO_GL=egl (or osmesa) before importing mujoco. "
                    f"The error was: {exc}"
                ) from exc
        self._renderer.update_scene(self.data, camera="overview")
        frame: NDArray[np.uint8] = self._renderer.render()
        return frame

    def close(self) -> None:
        """Release the renderer, if any; safe to call more than once."""
        renderer, self._renderer = getattr(self, "_renderer", None), None
        if renderer is not None:
            renderer.close()
        super().close()

    # ------------------------------------------------------------------ helpers
    def _snapshot(self) -> None:
        self._q = self._qpos.tolist()
        self._v = self._qvel.tolist()

    @staticmethod
    def _outside(pos: list[float], low: tuple[float, ...], high: tuple[float, ...]) -> bool:
        """Whether ``pos`` lies outside the box ``[low, high]``."""
        return any(p < lo or p > hi for p, lo, hi in zip(pos, low, high, strict=True))
