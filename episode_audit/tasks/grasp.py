"""``episode_audit/Grasp-v0``: pick a block up with a two-finger gripper and hold it.

- :class:`GraspEnv` -- the environment.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from ._base import MujocoTaskEnv
from ._layout import GRASP_ID
from ._layout import GraspLayout as L

__all__ = ["GraspEnv"]

_NOISE_PALM = (0.05, 0.05, 0.02)


class GraspEnv(MujocoTaskEnv):
    """Pick a 4 cm cube up from a table with a two-finger gripper and hold it in the air.

    The palm moves on x/y/z slide joints driven by velocity actuators (action ``a`` commands
    ``a`` m/s, forces limited to 20 N); two fingers slide along x under position control, gripping
    with at most 4 N each. 25 actions per second; registered with ``max_episode_steps=100``.

    Three predicates end an episode: a successful grasp (success), a dropped object (failure),
    and the time limit (truncation, from the registered ``TimeLimit`` only).

    **Observation** (float64, 14 entries)::

        0:3    palm position (m, world frame)
        3:6    palm velocity (m/s)
        6:8    opening of the left and right finger (m, 0 = closed, 0.05 = open)
        8:11   object position (m, its centre; 0.02 when resting on the table)
        11:14  object linear velocity (m/s)

    **Action** (float32, 4 entries in [-1, 1]): palm velocity command along x, y, z, then the
    grip: each finger's target opening is ``0.025 * (1 + a[3])`` (-1 closes, +1 opens fully).

    **Outcome** (``info["success"]``, ``info["failure"]``; each ends the episode):

    - success: the object's centre is above 0.12 m while touching both fingers, for 5
      consecutive steps;
    - ``dropped_object``: the object was lifted (centre above 0.05 m) and is back below 0.03 m;
    - ``safety_violation``: the palm leaves the workspace box
      ``[-0.3, 0.3] x [-0.3, 0.3] x [0.04, 0.45]``.

    **Reward terms** (``info["reward_terms"]``; the reward is their sum):

    - ``shaping``: ``0.99 * phi(s') - phi(s)`` with
      ``phi = -(|palm - grasp pose| + 5 * max(0.12 - object height, 0))``, the grasp pose being
      0.075 m above the object's centre, and ``phi = 0`` at termination;
    - ``ctrl_cost``: ``-0.01 * |a|^2``;
    - ``failure_penalty``: -5 on a failure step, else 0;
    - ``success_bonus``: +10 on the success step, else 0.

    With ``proxy_reward=True`` the ``shaping`` and ``failure_penalty`` terms are replaced by
    ``progress_velocity = 10 * max(object vertical velocity, 0)**2``: it pays for the object
    rising fast, held or not, so flinging it up scores well.

    Keyword arguments: ``render_mode`` (``None`` or ``"rgb_array"``), ``proxy_reward`` (above),
    ``width`` and ``height`` of rendered frames (at most 640 x 480).

    Example:
        >>> import gymnasium as gym
        >>> import numpy as np
        >>> import episode_audit.tasks
        >>> env = gym.make("episode_audit/Grasp-v0")
        >>> obs, info = env.reset(seed=1)
        >>> obs.shape, env.action_space.shape
        ((14,), (4,))
        >>> action = np.zeros(env.action_space.shape, dtype=np.float32)
        >>> obs, reward, terminated, truncated, info = env.step(action)
        >>> reward == sum(info["reward_terms"].values()), terminated, truncated
        (True, False, False)
        >>> env.close()

    Change logs:
        v0 - initial version.
    """

    task_id: ClassVar[str] = GRASP_ID
    model_file: ClassVar[str] = "grasp.xml"
    action_dim: ClassVar[int] = 4
    obs_low: ClassVar[tuple[float, ...]] = (
        (-10.0,) * 3 + (-50.0,) * 3 + (-0.1,) * 2 + (-10.0,) * 3 + (-50.0,) * 3
    )
    obs_high: ClassVar[tuple[float, ...]] = (
        (10.0,) * 3 + (50.0,) * 3 + (0.1,) * 2 + (10.0,) * 3 + (50.0,) * 3
    )
    proxy_weight: ClassVar[float] = 10.0

    def __init__(
        self,
        *,
        render_mode: str | None = None,
        proxy_reward: bool = False,
        width: int = 320,
        height: int = 240,
    ) -> None:
        super().__init__(
            render_mode=render_mode, proxy_reward=proxy_reward, width=width, height=height
        )
        model = self.model
        self._palm_q = int(model.joint("palm_x").qposadr[0])
        self._palm_v = int(model.joint("palm_x").dofadr[0])
        self._finger_q = (
            int(model.joint("finger_l").qposadr[0]),
            int(model.joint("finger_r").qposadr[0]),
        )
        self._obj_q = int(model.joint("object").qposadr[0])
        self._obj_v = int(model.joint("object").dofadr[0])
        self._touch = (int(model.sensor("touch_l").adr[0]), int(model.sensor("touch_r").adr[0]))
        self._lifted = False
        self._held_steps = 0

    def _randomize(self) -> None:
        rng = self.np_random
        qpos = self.data.qpos
        lim = L.OBJECT_START_RANGE
        qpos[self._obj_q : self._obj_q + 2] = rng.uniform(-lim, lim, 2)
        qpos[self._palm_q : self._palm_q + 3] = rng.uniform(-1.0, 1.0, 3) * _NOISE_PALM
        qpos[self._finger_q[0]] = L.FINGER_MAX
        qpos[self._finger_q[1]] = L.FINGER_MAX

    def _reset_episode_state(self) -> None:
        self._lifted = False
        self._held_steps = 0

    def _ctrl_from_action(self, action: list[float]) -> list[float]:
        opening = 0.5 * L.FINGER_MAX * (1.0 + action[3])
        return [action[0], action[1], action[2], opening, opening]

    def _palm_pos(self) -> list[float]:
        i = self._palm_q
        return [s + q for s, q in zip(L.PALM_START, self._q[i : i + 3], strict=True)]

    def _observe(self) -> NDArray[np.float64]:
        q, v = self._q, self._v
        i, j = self._obj_q, self._obj_v
        return np.array(
            [
                *self._palm_pos(),
                *v[self._palm_v : self._palm_v + 3],
                q[self._finger_q[0]],
                q[self._finger_q[1]],
                *q[i : i + 3],
                *v[j : j + 3],
            ],
            dtype=np.float64,
        )

    def _potential_of_state(self) -> float:
        x, y, z = self._q[self._obj_q : self._obj_q + 3]
        reach = math.dist(self._palm_pos(), (x, y, z + L.GRASP_DEPTH))
        return -(reach + 5.0 * max(L.LIFT_HEIGHT - z, 0.0))

    def _progress_speed(self) -> float:
        return self._v[self._obj_v + 2]

    def _outcome(self) -> tuple[bool, str | None]:
        height = self._q[self._obj_q + 2]
        if height >= L.LIFTED_HEIGHT:
            self._lifted = True
        elif self._lifted and height < L.DROPPED_HEIGHT:
            return False, "dropped_object"
        if self._outside(self._palm_pos(), L.WORKSPACE_LOW, L.WORKSPACE_HIGH):
            return False, "safety_violation"
        sensors = self._sensordata
        held = sensors[self._touch[0]] > 0 and sensors[self._touch[1]] > 0
        self._held_steps = self._held_steps + 1 if held and height >= L.LIFT_HEIGHT else 0
        return self._held_steps >= L.HOLD_STEPS, None
