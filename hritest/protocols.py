"""What a plugin implements: a robot policy, a human policy, a task. Plain Protocols, no base classes.

A plugin class sets ``kind`` (``"robot"``, ``"human"`` or ``"task"``) and may define a pydantic
``Params`` model: the spec's ``params`` and any theta-bound parameters are validated against it
when the spec is compiled. One plugin instance lives for one episode, so per-scenario
precomputation (a value table, waypoints) belongs in ``__init__``.

The data flows one way: the task builds observations from the world, policies return actions,
the task applies them and records a :class:`Rollout`. A policy never sees the simulator.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from hritest.scenario import Scenario


@dataclass(frozen=True)
class RobotAction:
    """A world-frame twist ``[vx, vy, vz, wx, wy, wz]``; for the task and recordings, the robot's
    belief over the human's goal and the goal it is heading for, when it has them."""

    twist: np.ndarray
    belief: np.ndarray | None = None
    goal: int | None = None


@runtime_checkable
class RobotPolicy(Protocol):
    kind: ClassVar[str]

    def __init__(self, *, params: Any, scenario: Scenario, rng: np.random.Generator) -> None: ...

    def act(self, observation: Mapping[str, Any]) -> RobotAction:
        """The action for this tick; the task documents the observation's keys."""
        ...


@runtime_checkable
class HumanPolicy(Protocol):
    kind: ClassVar[str]

    def __init__(self, *, params: Any, scenario: Scenario, rng: np.random.Generator) -> None: ...

    def act(self, observation: Mapping[str, Any]) -> np.ndarray:
        """The human's command for this tick (a velocity); the task documents both sides."""
        ...


@dataclass(frozen=True, kw_only=True)
class Rollout:
    """What happened in one episode, tick by tick, and the task's metrics over it.

    Arrays have one row per tick. ``states`` holds each agent's state-machine state per tick
    and ``events`` notable moments (goal reached, replanning, ...) as ``(time, text)``.
    """

    dt: float
    time: np.ndarray
    robot_ee: np.ndarray
    joints: np.ndarray
    human_hand: np.ndarray | None = None
    belief: np.ndarray | None = None
    states: Mapping[str, list[str]] = field(default_factory=dict)
    events: list[tuple[float, str]] = field(default_factory=list)
    metrics: Mapping[str, float] = field(default_factory=dict)
    occupancy: Mapping[str, np.ndarray] = field(default_factory=dict)


@runtime_checkable
class Task(Protocol):
    """The episode logic: builds the world, runs the tick loop, computes the metrics.

    ``metrics`` names every metric the task reports (the names a spec's expressions may use);
    ``agents`` names the moving agents whose 32x32 occupancy grids the surrogate predicts.
    """

    kind: ClassVar[str]
    metrics: ClassVar[tuple[str, ...]]
    agents: ClassVar[tuple[str, ...]]

    def __init__(self, *, params: Any, scenario: Scenario, spec: Any) -> None: ...

    def run(self, *, robot: RobotPolicy, human: HumanPolicy, rng: np.random.Generator) -> Rollout: ...
