"""The scene a spec describes, as a :class:`~hritest.sim.WorldLayout`: table, regions, goal boxes.

Tasks build their world from it and recordings draw it, so both show the same scene.
"""

from __future__ import annotations

from typing import Any

from hritest.scenario import Scenario
from hritest.sim.world import Box, WorldLayout

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
