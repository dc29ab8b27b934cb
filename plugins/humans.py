"""Human policies: the waypoint teleoperation user and the collaboration softmax-MDP human."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from hritest_plugins import mdp_human, teleop_human
from pydantic import BaseModel, ConfigDict, Field


class WaypointHuman:
    """The paper's simulated teleoperation user: noisy waypoints to the goal, joystick twists.

    The user plans 7 waypoints from ``start`` to its goal with ``waypoint_noise`` added to the
    5 interior y coordinates, steers the end effector toward the current one with the
    reference's saturated proportional command, and advances by the reference's rule.

    Observation: ``ee_position`` (3,), ``goal_position`` (3,). Returns the user's twist (6,).
    """

    kind: ClassVar[str] = "human"

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)
        start: tuple[float, float] = (0.41, 0.05)
        waypoint_noise: list[float] = Field(default_factory=lambda: [0.0] * (teleop_human.N_WAYPOINTS - 2))
        gain: float = Field(10.0, gt=0)
        max_command: float = Field(0.25, gt=0)
        joystick_weight: float = Field(0.2, gt=0, description="m/s per unit of command")

    def __init__(self, *, params: Params, scenario: Any, rng: np.random.Generator) -> None:
        self.params = params
        self.path: np.ndarray | None = None
        self.index = 0

    def act(self, observation: dict[str, Any]) -> np.ndarray:
        p = self.params
        ee = np.asarray(observation["ee_position"])
        if self.path is None:
            self.path = teleop_human.waypoints(p.start, observation["goal_position"], p.waypoint_noise)
        self.index, twist = teleop_human.user_step(
            self.index, self.path, ee, gain=p.gain, max_speed=p.max_command, weight=p.joystick_weight
        )
        return twist


class MdpHuman:
    """The collaboration human: moves to its current goal on a softmax-MDP grid policy.

    One soft value table per goal (other goals, the robot base and the unreachable quadrant as
    obstacles), computed on first need and kept for the episode. ``log10_rationality`` is the
    softmax inverse temperature's log (3 = the paper's 1000) and ``speed`` the velocity
    coefficient (0.5 = 0.125 m/s), the two human-model parameters the paper also searches.
    With ``stochastic`` the human samples its moves (seeded); otherwise it takes the best one.

    Observation: ``hand_position`` (3,), ``goal_position`` (3,), ``other_goals`` (k, 3).
    Returns the hand's velocity (3,) in m/s.
    """

    kind: ClassVar[str] = "human"

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)
        start: tuple[float, float] = mdp_human.HUMAN_START_XY
        log10_rationality: float = 3.0
        speed: float = Field(0.5, gt=0)
        stochastic: bool = False

    def __init__(self, *, params: Params, scenario: Any, rng: np.random.Generator) -> None:
        self.params = params
        self.rng = rng if params.stochastic else None
        self.grid = mdp_human.GridSpec()
        self.tables: dict[tuple[float, float], mdp_human.ValueTable] = {}

    def act(self, observation: dict[str, Any]) -> np.ndarray:
        goal = np.asarray(observation["goal_position"], dtype=float)
        hand = np.asarray(observation["hand_position"], dtype=float)
        table = self._table(goal, observation["other_goals"])
        target = mdp_human.next_target(table, hand, goal, rng=self.rng)
        velocity = np.zeros(3)
        velocity[:2] = teleop_human.user_velocity(hand, target) * self.params.speed
        return velocity

    def _table(self, goal: np.ndarray, other_goals: Any) -> mdp_human.ValueTable:
        key = (float(goal[0]), float(goal[1]))
        if key not in self.tables:
            others = np.asarray(other_goals, dtype=float).reshape(-1, 3)[:, :2]
            obstacles = mdp_human.obstacle_mask(self.grid, other_goals_xy=others)
            self.tables[key] = mdp_human.soft_value_iteration(
                self.grid, obstacles, tuple(self.grid.cell_of(goal)), tau=10.0**self.params.log10_rationality
            )
        return self.tables[key]
