"""The action the bundled tabletop robots return and their tasks read, and the tasks' check of
what any policy returns.

hritest's core never reads actions: what a policy returns is agreed between a task and its
policies. The paper's two tasks and three robots agree on this one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RobotAction:
    """A world-frame twist ``[vx, vy, vz, wx, wy, wz]``; for the task and recordings, the robot's
    belief over the human's goal and the goal it is heading for, when it has them."""

    twist: np.ndarray
    belief: np.ndarray | None = None
    goal: int | None = None


def checked(value: np.ndarray, who: str, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a float array of ``shape``, or a ValueError naming the plugin at fault."""
    array = np.asarray(value, dtype=float)
    if array.shape != shape:
        raise ValueError(f"{who} returned shape {array.shape}, expected {shape}")
    if not all(map(math.isfinite, array.flat)):  # plain floats: a handful of numbers, twice a tick
        raise ValueError(f"{who} returned a non-finite value: {array.tolist()}")
    return array
