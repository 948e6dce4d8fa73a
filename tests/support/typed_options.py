"""An env whose reset reads its options as the Python and numpy types they were passed."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np


class TypedStart(gym.Env[Any, Any]):
    """A 2-D walk whose reset reads each option it knows by the type it was given, as envs do.

    - ``qpos``: a numpy array, the start, added in its own dtype (a float32 start rounds as
      float32; ``.dtype`` / ``.size`` of a list raise);
    - ``goal``: a tuple is one point to start from, a list the points of a path (its last);
    - ``cap``: a number the start is capped at (``inf``: none);
    - ``scale``: a numpy scalar, the start scaled in its dtype;
    - ``levels``: a dict of level number -> factor (int keys), level 1's taken;
    - ``mask``: a numpy bool array, the coordinates kept (``.any()`` of a list raises).
    """

    observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float64)
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed: int | None = None, options: dict[Any, Any] | None = None) -> Any:
        super().reset(seed=seed)
        x = self.np_random.uniform(-1, 1, size=2)
        o = options or {}
        if "qpos" in o:
            q = o["qpos"]
            x = (q.reshape(-1) + x[: q.size].astype(q.dtype) / 3).astype(np.float64)
        if "goal" in o:
            goal = o["goal"]
            x = x + np.asarray(goal if isinstance(goal, tuple) else goal[-1], np.float64)
        if "cap" in o:
            x = np.minimum(x, o["cap"])
        if "scale" in o:
            x = (x.astype(o["scale"].dtype) * o["scale"]).astype(np.float64)
        if "levels" in o:
            x = x * o["levels"][1]
        if "mask" in o:
            x = np.where(o["mask"], x, 0.0) if o["mask"].any() else x
        self.x, self.t = x, 0
        return x.copy(), {}

    def step(self, action: Any) -> Any:
        self.t += 1
        self.x = self.x + (0.1 if int(action) else -0.1)
        return self.x.copy(), 1.0, False, self.t >= 3, {}


class Logger:
    """What reset options may carry that is no data: an object (its ``repr`` without an address)."""

    def __repr__(self) -> str:
        return "<Logger>"


class PoppingStart(TypedStart):
    """:class:`TypedStart` that takes ``goal`` out of the options it was given, as envs do."""

    def reset(self, *, seed: int | None = None, options: dict[Any, Any] | None = None) -> Any:
        obs = super().reset(seed=seed, options=options)
        if options is not None:
            options.pop("goal", None)
        return obs


class NoneOrEmpty(TypedStart):
    """:class:`TypedStart` whose start tells ``options=None`` from ``options={}``."""

    def reset(self, *, seed: int | None = None, options: dict[Any, Any] | None = None) -> Any:
        obs, info = super().reset(seed=seed, options=options)
        self.x = obs + (0.0 if options is None else 10.0)
        return self.x.copy(), info
