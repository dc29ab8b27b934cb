"""What a plugin implements: a robot policy, a human policy, a task. Plain Protocols, no base classes.

A plugin class sets ``kind`` (``"robot"``, ``"human"`` or ``"task"``) and may define a pydantic
``Params`` model: the spec's ``params`` and any theta-bound parameters are validated against it
when the spec is compiled. One plugin instance lives for one episode, so per-scenario
precomputation (a value table, waypoints) belongs in ``__init__``.

The data flows one way: the task builds observations from its simulator, policies return
actions, the task applies them and records a :class:`Rollout`. A policy never sees the
simulator, and a task never sees the spec: it gets a :class:`TaskContext`. What an observation
holds and what an action is are agreed between a task and its policies (the bundled tabletop
plugins use :class:`hritest_plugins.actions.RobotAction`); hritest itself reads neither.

``docs/writing-a-domain.md`` walks through writing all three.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np

from hritest.scenario import Scenario
from hritest.sim.layout import SceneTrace, WorldLayout

Observation = Mapping[str, object]


@runtime_checkable
class RobotPolicy(Protocol):
    kind: ClassVar[str]

    def __init__(self, *, params: object, scenario: Scenario, rng: np.random.Generator) -> None: ...

    def act(self, observation: Observation) -> object:
        """The action for this tick; the task documents the observation's keys and the action."""
        ...


@runtime_checkable
class HumanPolicy(Protocol):
    kind: ClassVar[str]

    def __init__(self, *, params: object, scenario: Scenario, rng: np.random.Generator) -> None: ...

    def act(self, observation: Observation) -> object:
        """The human's command for this tick; the task documents both sides."""
        ...


@dataclass(frozen=True, kw_only=True)
class TaskContext:
    """What a task gets to build one episode: never the spec, so the spec's format is not a plugin API.

    ``params`` is the task's validated ``Params`` (a dict if it has none) with theta-bound values
    set. ``world`` is the MuJoCo world this scenario describes (the spec's ``world`` and
    ``workspace`` sections, bodies where the scenario put them), ``None`` when the spec has neither;
    pass it to :func:`hritest.sim.shared_world`. ``folder`` is the spec's folder, for the task's
    own data files (``None`` for a spec that is not a file).
    """

    dt: float
    time_limit: float
    params: object
    scenario: Scenario
    world: WorldLayout | None = None
    folder: Path | None = None

    @property
    def ticks(self) -> int:
        """Ticks in the time limit."""
        return round(self.time_limit / self.dt)


@dataclass(frozen=True, kw_only=True)
class Rollout:
    """What happened in one episode and the task's metrics over it.

    Only ``dt``, ``time`` (one entry per recorded tick, seconds) and ``metrics`` are required.
    Everything else is optional and named by the task; recordings draw all of it:

    * ``trajectories``: name -> ``(ticks, 3)`` world positions of a body or point
      (``"robot/ee"``, ``"human/hand"``); ``/`` in a name groups entities in the viewer.
    * ``series``: name -> ``(n,)`` scalars over the first ``n`` ticks (a belief, a distance).
    * ``states``: agent -> its state-machine state per tick. ``events``: ``(time, text)``.
    * ``grids``: the occupancy grids the task declares in its ``grids`` class attribute, each of
      the declared shape; the SAS/DSAS surrogate learns them (without any, it predicts from
      theta alone).
    * ``scene``: a :class:`hritest.sim.SceneTrace` of the MuJoCo world the task ran, so the
      recording shows every body of it.
    """

    dt: float
    time: np.ndarray
    metrics: Mapping[str, float]
    trajectories: Mapping[str, np.ndarray] = field(default_factory=dict)
    series: Mapping[str, np.ndarray] = field(default_factory=dict)
    states: Mapping[str, Sequence[str]] = field(default_factory=dict)
    events: Sequence[tuple[float, str]] = ()
    grids: Mapping[str, np.ndarray] = field(default_factory=dict)
    scene: SceneTrace | None = None


@runtime_checkable
class Task(Protocol):
    """The episode logic: builds its world, runs the tick loop, computes the metrics.

    ``metrics`` names every metric the task reports (the names a spec's expressions may use);
    ``grids`` maps each occupancy grid the task returns to its shape (``{}``: none). The
    surrogate's networks take ``(32, 32)`` grids, the paper's; see :func:`hritest.metrics.occupancy_grid`.
    """

    kind: ClassVar[str]
    metrics: ClassVar[tuple[str, ...]]
    grids: ClassVar[Mapping[str, tuple[int, int]]]

    def __init__(self, *, context: TaskContext) -> None: ...

    def run(self, *, robot: RobotPolicy, human: HumanPolicy, rng: np.random.Generator) -> Rollout: ...
