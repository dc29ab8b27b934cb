"""What both tasks share: the MuJoCo world built from a spec, goal checks, tick records."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from hritest.scenario import Scenario
from hritest.sim import Box, WorldLayout
from hritest_plugins import hindsight

REGION_COLOUR = (0.55, 0.75, 0.95, 0.6)
GOAL_COLOUR = (0.9, 0.5, 0.1, 1.0)


def world_layout(spec: Any, scenario: Scenario, *, hand_start: tuple[float, float, float] | None) -> WorldLayout:
    """The table, regions and goal boxes of ``spec`` with the objects where ``scenario`` puts them."""
    table = spec.workspace.table
    top = table.center[2] + table.half_size[2]
    regions = tuple(
        Box(name=r.name, center=((r.x[0] + r.x[1]) / 2, (r.y[0] + r.y[1]) / 2, top + 0.001),
            half_size=((r.x[1] - r.x[0]) / 2, (r.y[1] - r.y[0]) / 2, 0.001), rgba=REGION_COLOUR)
        for r in spec.workspace.regions
    )
    objects = tuple(
        Box(name=o.name, center=tuple(float(v) for v in scenario.objects[o.name]), half_size=o.half_size,
            rgba=GOAL_COLOUR)
        for o in spec.objects
    )
    return WorldLayout(table=Box(name="table", center=table.center, half_size=table.half_size),
                       regions=regions, objects=objects, hand_start=hand_start)


def goal_targets(scenario: Scenario, names: list[str]) -> np.ndarray:
    """``(goals, 2, 4, 4)``: each goal's two target end-effector poses, read-only.

    Read-only because robots prepare it once (:func:`hindsight.prepare_targets`) and then
    recognise it by identity on every tick.
    """
    targets = np.stack([hindsight.target_poses(scenario.objects[name]) for name in names])
    targets.flags.writeable = False
    return targets


def at_goal(pose: np.ndarray, targets: hindsight.Targets | np.ndarray, *, distance: float, angle: float) -> bool:
    """Whether ``pose`` is within ``distance`` (m) and ``angle`` (rad) of any of ``targets``.

    Pass :class:`hindsight.Targets` when checking every tick.
    """
    if min(hindsight.distances(pose, targets)) >= distance:
        return False  # too far from every target: no need for the rotations
    return any(o.distance < distance and o.angle < angle for o in hindsight.offsets(pose, targets))


def checked(value: np.ndarray, who: str, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a float array of ``shape``, or a ValueError naming the plugin at fault."""
    array = np.asarray(value, dtype=float)
    if array.shape != shape:
        raise ValueError(f"{who} returned shape {array.shape}, expected {shape}")
    if not all(map(math.isfinite, array.flat)):  # plain floats: a handful of numbers, twice a tick
        raise ValueError(f"{who} returned a non-finite value: {array.tolist()}")
    return array
