"""Reference MuJoCo tasks of episode-audit, registered with Gymnasium on import.

- ``episode_audit/DoorOpen-v0`` (:class:`~episode_audit.tasks.door.DoorOpenEnv`) -- push a
  hinged door open past a target angle and let it come to rest.
- ``episode_audit/DrawerOpen-v0`` (:class:`~episode_audit.tasks.drawer.DrawerOpenEnv`) -- hook a
  drawer's handle and pull it out past a target displacement, gently.
- ``episode_audit/Grasp-v0`` (:class:`~episode_audit.tasks.grasp.GraspEnv`) -- pick a block
  up with a two-finger gripper and hold it in the air.
- :func:`~episode_audit.tasks.policies.make_policy` -- scripted, random and reward-hacking
  policies for them (:data:`~episode_audit.tasks.policies.POLICY_NAMES`).

Every step's ``info`` holds ``reward_terms`` (the reward is their sum), ``success`` and
``failure`` (a label on a terminal failure step, else ``None``); truncation comes only from the
registered time limit. ``proxy_reward=True`` swaps in a misaligned reward that pays for speed.
Registration uses entry-point strings, so importing this package does not import MuJoCo.

Example:
    >>> import gymnasium as gym
    >>> import episode_audit.tasks
    >>> from episode_audit.tasks import TASK_IDS, make_policy
    >>> TASK_IDS
    ('episode_audit/DoorOpen-v0', 'episode_audit/DrawerOpen-v0', 'episode_audit/Grasp-v0')
    >>> env = gym.make("episode_audit/DrawerOpen-v0")
    >>> policy = make_policy("scripted", env)
    >>> obs, info = env.reset(seed=0)
    >>> terminated = truncated = False
    >>> while not (terminated or truncated):
    ...     obs, reward, terminated, truncated, info = env.step(policy(obs))
    >>> info["success"], info["failure"]
    (True, None)
    >>> env.close()
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Final

import gymnasium as gym

from ._layout import DOOR_OPEN_ID, DRAWER_OPEN_ID, GRASP_ID
from .policies import POLICY_NAMES, make_policy

__all__ = [
    "DOOR_OPEN_ID",
    "DRAWER_OPEN_ID",
    "GRASP_ID",
    "MAX_EPISODE_STEPS",
    "POLICY_NAMES",
    "TASK_IDS",
    "make_policy",
]

TASK_IDS: Final = (DOOR_OPEN_ID, DRAWER_OPEN_ID, GRASP_ID)

MAX_EPISODE_STEPS: Final = MappingProxyType({DOOR_OPEN_ID: 150, DRAWER_OPEN_ID: 120, GRASP_ID: 100})
"""Time limit of each task in steps (40 ms each); the only source of truncation."""

_ENTRY_POINTS: Final = {
    DOOR_OPEN_ID: "episode_audit.tasks.door:DoorOpenEnv",
    DRAWER_OPEN_ID: "episode_audit.tasks.drawer:DrawerOpenEnv",
    GRASP_ID: "episode_audit.tasks.grasp:GraspEnv",
}

for _env_id, _entry_point in _ENTRY_POINTS.items():
    # Re-importing (e.g. under another module name) must not warn about overriding.
    if _env_id not in gym.registry:
        gym.register(
            id=_env_id,
            entry_point=_entry_point,
            max_episode_steps=MAX_EPISODE_STEPS[_env_id],
        )
