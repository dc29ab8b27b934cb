"""What both tasks share: goal targets, goal checks, checked plugin outputs."""

from __future__ import annotations

import math

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


def checked(value: np.ndarray, who: str, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a float array of ``shape``, or a ValueError naming the plugin at fault."""
    array = np.asarray(value, dtype=float)
    if array.shape != shape:
        raise ValueError(f"{who} returned shape {array.shape}, expected {shape}")
    if not all(map(math.isfinite, array.flat)):  # plain floats: a handful of numbers, twice a tick
        raise ValueError(f"{who} returned a non-finite value: {array.tolist()}")
    return array
