"""A corridor robot and a pedestrian who crosses its path: a domain with its own simulator.

hritest needs no MuJoCo to search a domain: this task is 2-D kinematics in plain Python and
numpy, a few hundred ticks in about a millisecond. The robot drives along the corridor's centre
line, x from 0 to ``corridor_length``; the pedestrian walks across it, in +y, at ``crossing_x``.

What the three plugins agree on (hritest itself reads neither observations nor actions):

* the robot sees ``time``, ``dt``, ``robot_position`` (x, y), ``robot_speed``,
  ``human_position`` and ``human_velocity``, and returns the speed it wants (m/s, a float);
* the pedestrian sees ``time``, ``dt``, ``human_position``, ``robot_position``, ``robot_speed``
  and ``corridor_half_width``, and returns its velocity (an array of 2, m/s).
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from hritest.protocols import HumanPolicy, Observation, RobotPolicy, Rollout, TaskContext
from hritest.scenario import Scenario

START_Y = -2.5  # m: where the pedestrian stands before it sets off; it stops at -START_Y
STILL = 1e-6  # m/s: a robot slower than this stands still


class CrossingTask:
    """The episode: it ends when the robot reaches its goal, touches the pedestrian, or at the time limit.

    A collision ends the episode unfinished, so its completion time is the time limit: the
    objective (completion time, higher is worse) rates touching a person as badly as never
    arriving. The pedestrian's start is the one thing the task reads from the human's
    parameters (``crossing_x``): where a person crosses belongs to the person's model.
    """

    kind: ClassVar[str] = "task"
    metrics: ClassVar[tuple[str, ...]] = ("completion_time", "min_distance", "time_stopped", "closest_speed")
    grids: ClassVar[dict[str, tuple[int, int]]] = {}  # none: SAS/DSAS predict from theta alone

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)
        corridor_length: float = Field(10.0, gt=0, description="m from the robot's start to its goal")
        corridor_half_width: float = Field(1.0, gt=0, description="m from the centre line to each wall")
        robot_radius: float = Field(0.3, gt=0, description="m")
        human_radius: float = Field(0.25, gt=0, description="m")
        acceleration: float = Field(1.0, gt=0, description="m/s^2 the robot's drive can speed up")
        deceleration: float = Field(1.5, gt=0, description="m/s^2 its brakes can slow it down")

    def __init__(self, *, context: TaskContext) -> None:
        self.params: CrossingTask.Params = context.params
        self.dt = context.dt
        self.ticks = context.ticks
        self.crossing_x = float(context.scenario.human["crossing_x"])

    def run(self, *, robot: RobotPolicy, human: HumanPolicy, rng: np.random.Generator) -> Rollout:
        p, dt = self.params, self.dt
        contact = p.robot_radius + p.human_radius
        robot_x, speed = 0.0, 0.0
        human_x, human_y, human_velocity = self.crossing_x, START_Y, (0.0, 0.0)
        path, events = [], []  # path: (robot x, human x, human y, robot speed, distance) per tick
        reached = False
        for tick in range(self.ticks + 1):
            now = tick * dt
            distance = math.hypot(human_x - robot_x, human_y)
            path.append((robot_x, human_x, human_y, speed, distance))
            if distance < contact:
                events.append((now, f"collision at {speed:.2f} m/s"))
                break
            if robot_x >= p.corridor_length:
                reached = True
                events.append((now, "robot reached its goal"))
                break
            if tick == self.ticks:
                break
            robot_xy, human_xy = np.array([robot_x, 0.0]), np.array([human_x, human_y])
            wanted = float(
                robot.act(
                    {
                        "time": now,
                        "dt": dt,
                        "robot_position": robot_xy,
                        "robot_speed": speed,
                        "human_position": human_xy,
                        "human_velocity": np.array(human_velocity),
                    }
                )
            )
            human_velocity = _velocity(
                human.act(
                    {
                        "time": now,
                        "dt": dt,
                        "human_position": human_xy,
                        "robot_position": robot_xy,
                        "robot_speed": speed,
                        "corridor_half_width": p.corridor_half_width,
                    }
                ),
                human,
            )
            moving = speed >= STILL
            speed = max(0.0, speed + min(max(wanted - speed, -p.deceleration * dt), p.acceleration * dt))
            if moving and speed < STILL:
                events.append((now + dt, "robot stopped"))
            robot_x += speed * dt
            human_x += human_velocity[0] * dt
            human_y += human_velocity[1] * dt
        robot_xs, human_xs, human_ys, speeds, distances = np.array(path).T
        closest = int(np.argmin(distances))
        floor = np.zeros(len(path))
        return Rollout(
            dt=dt,
            time=np.arange(len(path)) * dt,
            metrics={
                "completion_time": (len(path) - 1) * dt if reached else self.ticks * dt,
                "min_distance": float(distances[closest]),
                "time_stopped": float(np.count_nonzero(speeds[1:] < STILL) * dt),
                "closest_speed": float(speeds[closest]),
            },
            trajectories={
                "robot": np.column_stack([robot_xs, floor, floor]),
                "human": np.column_stack([human_xs, human_ys, floor]),
            },
            series={"distance": distances, "robot_speed": speeds},
            events=events,
        )


def _velocity(action: np.ndarray, human: HumanPolicy) -> tuple[float, float]:
    """The pedestrian's action as (vx, vy), or an error that names the plugin to fix."""
    try:
        vx, vy = (float(v) for v in action)
    except (TypeError, ValueError):
        vx = vy = math.nan
    if not (math.isfinite(vx) and math.isfinite(vy)):
        raise ValueError(f"{type(human).__name__}.act must return a finite velocity (vx, vy), got {action!r}")
    return vx, vy


class CautiousRobot:
    """Drives at ``max_speed``, and stops while a tracked pedestrian would come closer than ``safety_distance``.

    Each tick it predicts the closest approach if it drove on at ``max_speed`` and the pedestrian
    kept its velocity. Two limits make it fail, which is what the search is for: it acts on what
    it saw ``reaction_time`` ago, and it tracks only people within ``track_width`` of its path
    (its laser covers the corridor), so a pedestrian who steps out late is seen late.
    """

    kind: ClassVar[str] = "robot"

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)
        max_speed: float = Field(1.0, gt=0, description="m/s the robot cruises at")
        safety_distance: float = Field(1.0, ge=0, description="m between centres it keeps from a pedestrian")
        reaction_time: float = Field(0.4, ge=0, description="s between seeing the pedestrian and acting on it")
        track_width: float = Field(1.0, ge=0, description="m either side of its path in which it sees people")
        horizon: float = Field(3.0, gt=0, description="s ahead it predicts")

    def __init__(self, *, params: Params, scenario: Scenario, rng: np.random.Generator) -> None:
        self.params = params
        self.seen: list[tuple[float, float, float, float]] = []  # the pedestrian's x, y, vx, vy per tick

    def act(self, observation: Observation) -> float:
        p = self.params
        self.seen.append((*observation["human_position"].tolist(), *observation["human_velocity"].tolist()))
        lag = round(p.reaction_time / observation["dt"])
        hx, hy, vx, vy = self.seen[max(0, len(self.seen) - 1 - lag)]
        if abs(hy) > p.track_width:  # outside its sensor
            return p.max_speed
        dx, dy = hx - observation["robot_position"][0].item(), hy
        cx = vx - p.max_speed  # the pedestrian's velocity relative to the robot driving on
        approach = -(dx * cx + dy * vy)
        if approach <= 0:  # moving apart: the closest approach is now, and it only grows
            return p.max_speed
        when = min(approach / (cx * cx + vy * vy), p.horizon)
        closest = math.hypot(dx + cx * when, dy + vy * when)
        return 0.0 if closest < p.safety_distance else p.max_speed


class Pedestrian:
    """Waits ``delay``, walks to the corridor's edge and across it at ``speed``.

    At the edge it lets an approaching robot pass, but for at most ``patience`` seconds: an
    impatient pedestrian steps out in front of it. It never walks into a robot: it waits for
    one in its way to move (and a robot that stopped for it waits too: a deadlock).
    """

    kind: ClassVar[str] = "human"

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)
        crossing_x: float = Field(6.0, ge=0, description="m along the corridor where it crosses")
        speed: float = Field(1.2, gt=0, description="m/s walking speed")
        delay: float = Field(1.0, ge=0, description="s before it sets off")
        patience: float = Field(2.0, ge=0, description="s it waits at the edge for an approaching robot")
        look_distance: float = Field(3.0, ge=0, description="m: a moving robot nearer than this is approaching")
        speed_jitter: float = Field(0.05, ge=0, description="relative spread of its speed, drawn per episode")

    def __init__(self, *, params: Params, scenario: Scenario, rng: np.random.Generator) -> None:
        self.params = params
        self.speed = params.speed * max(0.1, 1.0 + params.speed_jitter * rng.standard_normal())
        self.waited = 0.0

    def act(self, observation: Observation) -> np.ndarray:
        p, dt = self.params, observation["dt"]
        x, y = observation["human_position"].tolist()
        robot_x = observation["robot_position"][0].item()
        if observation["time"] < p.delay or y >= -START_Y:
            return np.zeros(2)
        step = self.speed * dt
        edge = -observation["corridor_half_width"] - 0.3
        approaching = 0.0 < x - robot_x < p.look_distance and observation["robot_speed"] > 0.1
        if y < edge <= y + step and approaching and self.waited < p.patience:
            self.waited += dt
            return np.zeros(2)
        gap, next_gap = math.hypot(x - robot_x, y), math.hypot(x - robot_x, y + step)
        if next_gap < min(gap, 0.8):  # the next step walks into the robot
            return np.zeros(2)
        return np.array([0.0, self.speed])
