"""The goals both tabletop tasks share: each goal's target poses, and whether a pose has reached one."""

from __future__ import annotations

import numpy as np
from hritest_plugins import poses

from hritest.scenario import Scenario


def goal_targets(scenario: Scenario, names: list[str]) -> np.ndarray:
    """``(goals, 2, 4, 4)``: each goal's two target end-effector poses, read-only.

    Read-only because robots prepare it once (:func:`poses.prepare_targets`) and then
    recognise it by identity on every tick.
    """
    targets = np.stack([poses.target_poses(scenario.objects[name]) for name in names])
    targets.flags.writeable = False
    return targets


def at_goal(pose: np.ndarray, targets: poses.Targets | np.ndarray, *, distance: float, angle: float) -> bool:
    """Whether ``pose`` is within ``distance`` (m) and ``angle`` (rad) of any of ``targets``.

    Pass :class:`poses.Targets` when checking every tick.
    """
    return poses.within(pose, targets, distance=distance, angle=angle)
