"""The action the bundled tabletop robots return and their tasks read.

hritest's core never reads actions: what a policy returns is agreed between a task and its
policies. The paper's two tasks and three robots agree on this one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RobotAction:
    """A world-frame twist ``[vx, vy, vz, wx, wy, wz]``; for the task and recordings, the robot's
    belief over the human's goal and the goal it is heading for, when it has them."""

    twist: np.ndarray
    belief: np.ndarray | None = None
    goal: int | None = None
