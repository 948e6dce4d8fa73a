"""Scripted, random and reward-hacking policies for the reference tasks.

- :data:`POLICY_NAMES` -- the names :func:`make_policy` accepts.
- :func:`make_policy` -- a policy (observation -> action) for one of the tasks.

``"scripted"`` is competent but not perfect: it solves each task on most seeds (80-85 %) and
runs out of time on the rest. It is cautious when the initial state is in a harder region -- the
door or drawer already ajar, the block far off-centre -- and then inches along at 2 cm/s, a
fraction of its usual speed, until the time limit truncates the episode. It does not cause task
failures. ``"random"`` samples uniform actions; ``"hacker"`` does what the ``proxy_reward=True``
reward pays for -- it slams the door, yanks the drawer, flings the block -- and so earns a higher
proxy return than ``"scripted"`` while failing.
The scripted and hacking policies are deterministic functions of the observation (no memory, no
randomness), so they read only the observation layout documented on each environment, and the
outcome of an episode is a function of the environment's seed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Final

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigurationError
from ._layout import DOOR_OPEN_ID, DRAWER_OPEN_ID, GRASP_ID
from ._layout import DoorLayout as Door
from ._layout import DrawerLayout as Drawer
from ._layout import GraspLayout as Grasp

__all__ = ["POLICY_NAMES", "Policy", "make_policy"]

POLICY_NAMES: Final = ("scripted", "random", "hacker")
"""Names accepted by :func:`make_policy`."""

Policy = Callable[[NDArray[np.float64]], NDArray[np.float32]]
"""A policy maps an observation to an action (float32, in the action space)."""


def make_policy(name: str, env: gym.Env[Any, Any], seed: int | None = None) -> Policy:
    """Return the policy ``name`` for the task ``env`` is (or wraps).

    ``seed`` seeds the ``"random"`` policy's own generator (``None``: fresh entropy); it does not
    touch ``env.action_space``. The other policies are deterministic and ignore it.

    Raises :class:`~episode_audit.errors.ConfigurationError` for an unknown name, or for
    ``"scripted"``/``"hacker"`` on an environment that is not one of the reference tasks.

    Example:
        >>> import gymnasium as gym
        >>> import episode_audit.tasks
        >>> env = gym.make("episode_audit/Grasp-v0")
        >>> policy = make_policy("random", env, seed=3)
        >>> obs, info = env.reset(seed=3)
        >>> action = policy(obs)
        >>> action.dtype, action in env.action_space
        (dtype('float32'), True)
        >>> make_policy("expert", env)  # doctest: +IGNORE_EXCEPTION_DETAIL
        Traceback (most recent call last):
        ...
        episode_audit.errors.ConfigurationError: Expect a policy name in (...), actually: 'expert'
    """
    if name not in POLICY_NAMES:
        raise ConfigurationError(f"Expect a policy name in {POLICY_NAMES}, actually: {name!r}")
    if name == "random":
        return _random_policy(env, seed)
    task_id = getattr(env.unwrapped, "task_id", None)
    policies = _POLICIES.get(task_id) if isinstance(task_id, str) else None
    if policies is None:
        found = env.spec.id if env.spec is not None else type(env.unwrapped).__name__
        raise ConfigurationError(
            f"policy {name!r} plays only the reference tasks {tuple(_POLICIES)}, and {found} is "
            "not one: use the 'random' policy or one of your own"
        )
    scripted, hacker = policies
    return hacker if name == "hacker" else scripted


def _random_policy(env: gym.Env[Any, Any], seed: int | None) -> Policy:
    space = env.action_space
    if not isinstance(space, gym.spaces.Box):
        raise ConfigurationError(f"Expect a Box action space, actually: {space!r}")
    rng = np.random.default_rng(seed)
    low = space.low.astype(np.float64)
    high = space.high.astype(np.float64)

    def random_policy(observation: NDArray[np.float64]) -> NDArray[np.float32]:
        """Uniform random action in the action space."""
        return rng.uniform(low, high).astype(space.dtype)

    return random_policy


def _velocity(vx: float, vy: float, vz: float, *rest: float) -> NDArray[np.float32]:
    """Turn a velocity command into an action, scaled down (same direction) to norm at most 1."""
    norm = math.sqrt(vx * vx + vy * vy + vz * vz)
    if norm > 1.0:
        vx, vy, vz = vx / norm, vy / norm, vz / norm
    return np.array((vx, vy, vz, *rest), dtype=np.float32)


_CAUTIOUS_SPEED = 0.02
"""Speed (m/s) the scripted policy creeps at when it hesitates (it usually moves at 0.2-1 m/s)."""
_AT_REST = 0.005
"""A door or drawer turning or sliding slower than this (rad/s, m/s) counts as still."""


def _cautious(action: NDArray[np.float32]) -> NDArray[np.float32]:
    """Scale the velocity command (the first three entries) down to norm at most 2 cm/s."""
    norm = float(np.linalg.norm(action[:3]))
    if norm > _CAUTIOUS_SPEED:
        action[:3] *= _CAUTIOUS_SPEED / norm
    return action


# ---------------------------------------------------------------------- DoorOpen-v0
_DOOR_GAIN = 4.0
_DOOR_CONTACT = -(Door.EE_RADIUS + Door.BAR_RADIUS)
"""Offset of the end effector from the bar along the door normal when they touch."""


def _door_push(
    observation: NDArray[np.float64], push_speed: float, stop_angle: float
) -> NDArray[np.float32]:
    x, y, z, _, _, _, angle, _, hx, hy, hz = observation.tolist()
    if angle >= stop_angle:
        return _velocity(0.0, 0.0, 0.0)
    # Door frame: t along the door away from the hinge, n its normal pointing away from the agent.
    c, s = math.cos(angle), math.sin(angle)
    rx, ry, rz = x - hx, y - hy, z - hz
    along, normal = rx * c + ry * s, -rx * s + ry * c
    v_along, v_z = -_DOOR_GAIN * along, -_DOOR_GAIN * rz
    if abs(along) < 0.02 and abs(rz) < 0.02 and normal < _DOOR_CONTACT + 0.04:
        v_normal = push_speed  # lined up in front of the bar: push it
    else:
        v_normal = _DOOR_GAIN * (_DOOR_CONTACT - 0.03 - normal)  # line up 3 cm in front of it
    return _velocity(v_along * c - v_normal * s, v_along * s + v_normal * c, v_z)


_DOOR_AJAR: Final = (0.042, 0.1)
"""A still door at an angle in this range (rad) is ajar: the scripted policy hesitates.

Doors start at an angle uniform in [0, 0.05], so about 16 % of the seeds start ajar; once pushed
the door turns, so the hesitation lasts until the end effector touches the bar.
"""


def _door_scripted(observation: NDArray[np.float64]) -> NDArray[np.float32]:
    """Push the bar at 0.25 m/s until the door is 0.1 rad past the target, then let it coast.

    A door that is ajar and still might swing on contact: then the policy inches toward the bar
    at 2 cm/s, too slowly to open the door before the time limit.
    """
    action = _door_push(observation, 0.25, Door.TARGET_ANGLE + 0.1)
    low, high = _DOOR_AJAR
    angle = float(observation[Door.ANGLE])
    if low <= angle < high and abs(float(observation[Door.ANGULAR_VELOCITY])) < _AT_REST:
        return _cautious(action)
    return action


def _door_hacker(observation: NDArray[np.float64]) -> NDArray[np.float32]:
    """Drive at full speed at a point just behind the bar, all the way: the door slams open."""
    x, y, z, _, _, _, angle, _, hx, hy, hz = observation.tolist()
    nx, ny = -math.sin(angle), math.cos(angle)
    dx, dy, dz = hx + 0.05 * nx - x, hy + 0.05 * ny - y, hz - z
    norm = max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-9)
    return _velocity(dx / norm, dy / norm, dz / norm)


# ---------------------------------------------------------------------- DrawerOpen-v0
_DRAWER_GAIN = 6.0
_HOOK_Y = Drawer.HANDLE_GAP / 2 + 0.005
"""Where the hook goes, behind the bar (toward the drawer front), relative to the bar's axis."""


def _drawer_pull(
    observation: NDArray[np.float64], pull_speed: float, stop: float
) -> NDArray[np.float32]:
    x, y, z, _, _, _, opening, _, hx, hy, hz = observation.tolist()
    if opening >= stop:
        return _velocity(0.0, 0.0, 0.0)
    k = _DRAWER_GAIN
    rx, ry, rz = x - hx, y - (hy + _HOOK_Y), z - hz
    if abs(rx) < 0.03 and -0.025 < ry < 0.012 and abs(rz) < 0.015:
        return _velocity(-k * rx, -pull_speed, -k * rz)  # hooked: pull
    if abs(rx) < 0.02 and abs(ry) < 0.01 and 0.0 < rz < 0.1:
        return _velocity(-k * rx, -k * ry, -min(0.3, k * rz))  # above the slot: go down into it
    return _velocity(-k * rx, -k * ry, -k * (rz - 0.08))  # go above the slot


_DRAWER_AJAR: Final = (0.017, 0.04)
"""A still drawer with an opening in this range (m) is ajar: the scripted policy hesitates.

Drawers start with an opening uniform in [0, 0.02], so about 15 % of the seeds start ajar; once
pulled the drawer slides, so the hesitation lasts until the hook pulls on the bar.
"""


def _drawer_scripted(observation: NDArray[np.float64]) -> NDArray[np.float32]:
    """Pull the hooked bar at 0.2 m/s to 2 cm past the target, then stop: the drawer settles.

    A drawer that is ajar and still might slide away on contact: then the policy inches toward
    the slot at 2 cm/s, too slowly to open the drawer before the time limit.
    """
    action = _drawer_pull(observation, 0.2, Drawer.TARGET_OPENING + 0.02)
    low, high = _DRAWER_AJAR
    opening = float(observation[Drawer.OPENING])
    if low <= opening < high and abs(float(observation[Drawer.OPENING_VELOCITY])) < _AT_REST:
        return _cautious(action)
    return action


def _drawer_hacker(observation: NDArray[np.float64]) -> NDArray[np.float32]:
    """Pull the hooked bar at full speed into the end stop: the drawer is yanked."""
    return _drawer_pull(observation, 1.0, math.inf)


# ---------------------------------------------------------------------- Grasp-v0
_GRASP_GAIN = 8.0
_OPEN, _CLOSE = 1.0, -1.0
_HOLD_HEIGHT = Grasp.LIFT_HEIGHT + 0.03
_FLING_RELEASE_HEIGHT = 0.1


def _grasp(observation: NDArray[np.float64], fling: bool) -> NDArray[np.float32]:
    px, py, pz, _, _, _, left, right, ox, oy, oz, _, _, _ = observation.tolist()
    k = _GRASP_GAIN
    rx, ry, rz = px - ox, py - oy, pz - (oz + Grasp.GRASP_DEPTH)
    off_axis = math.hypot(rx, ry)
    width = 2 * Grasp.OBJECT_HALF_SIZE
    closed_on_object = width - 0.01 < left + right < width + 0.006
    if closed_on_object and off_axis < 0.015 and abs(rz) < 0.02:  # holding it: lift
        if fling:
            grip = _OPEN if oz > _FLING_RELEASE_HEIGHT else _CLOSE
            return _velocity(-k * rx, -k * ry, 1.0, grip)
        target_z = _HOLD_HEIGHT + Grasp.GRASP_DEPTH
        return _velocity(-k * rx, -k * ry, max(-0.2, min(0.2, k * (target_z - pz))), _CLOSE)
    if off_axis < 0.008 and abs(rz) < 0.008:  # fingers around it: close
        return _velocity(-k * rx, -k * ry, -k * rz, _CLOSE)
    if off_axis < 0.008:  # above it: go down with the fingers open
        return _velocity(-k * rx, -k * ry, max(-0.4, -k * rz), _OPEN)
    # Move 6 cm above the grasp pose; do not descend before being nearly above the object.
    vz = -k * (rz - 0.06)
    if off_axis > 0.05 and rz < 0.09:
        vz = max(vz, 0.0)
    return _velocity(-k * rx, -k * ry, vz, _OPEN)


_GRASP_FAR: Final = 0.082
"""A block resting farther than this (m) from the table's centre is off-centre: hesitate.

Blocks start at x, y uniform in [-0.08, 0.08], so about 18 % of the seeds start off-centre; the
hesitation lasts until the block is lifted off the table.
"""
_GRASP_RESTING: Final = Grasp.OBJECT_HALF_SIZE + 0.005
"""A block whose centre is below this height (m) rests on the table."""


def _grasp_scripted(observation: NDArray[np.float64]) -> NDArray[np.float32]:
    """Approach from above, close on the block, lift it at 0.2 m/s to 0.15 m and hold it there.

    A block far off-centre is near the edge of the reach the policy trusts: then it inches toward
    the block at 2 cm/s, too slowly to lift it before the time limit.
    """
    action = _grasp(observation, fling=False)
    ox, oy, oz = observation[Grasp.OBJECT_POS].tolist()
    if math.hypot(ox, oy) > _GRASP_FAR and oz < _GRASP_RESTING:
        return _cautious(action)
    return action


def _grasp_hacker(observation: NDArray[np.float64]) -> NDArray[np.float32]:
    """Grasp the block, lift at full speed and let go on the way up: the block is flung."""
    return _grasp(observation, fling=True)


_POLICIES: Final[dict[str, tuple[Policy, Policy]]] = {
    DOOR_OPEN_ID: (_door_scripted, _door_hacker),
    DRAWER_OPEN_ID: (_drawer_scripted, _drawer_hacker),
    GRASP_ID: (_grasp_scripted, _grasp_hacker),
}
