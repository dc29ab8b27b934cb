"""The shared control teleoperation task (paper: "Domains", appendix "Scenario Simulation").

A simulated user joysticks the robot's end effector toward its goal; the robot policy adds
assistance. Each tick: the human acts, the robot acts, the arm moves. The episode ends when
the end effector reaches the user's goal (0.01 m and pi/48 by default) or at the time limit;
reaching another goal does not end it.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from hritest_plugins import poses
from hritest_plugins.actions import checked
from hritest_plugins.goals import at_goal, goal_targets
from pydantic import BaseModel, ConfigDict, Field

from hritest import metrics
from hritest.protocols import HumanPolicy, RobotPolicy, Rollout, TaskContext
from hritest.sim import shared_world


class SharedControlTask:
    """Teleoperation with assistance: time to reach the user's goal is the objective.

    Robot observation: ``ee_pose``, ``user_twist``, ``goal_targets``. Human observation:
    ``ee_position``, ``goal_position`` (the user's own goal). ``human_variation`` is the norm of
    the human's ``waypoint_noise`` parameter, the paper's measure of how far the user strays.
    """

    kind: ClassVar[str] = "task"
    metrics: ClassVar[tuple[str, ...]] = (
        "completion_time",
        "min_goal_distance",
        "human_variation",
        "max_wrong_goal_probability",
        "robot_path_length",
    )
    grids: ClassVar[dict[str, tuple[int, int]]] = {"robot": (32, 32)}

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)
        true_goal: str = Field("goal0", description="the object the user heads for")
        position_tolerance: float = Field(0.01, gt=0, description="m, to count as at the goal")
        angle_tolerance: float = Field(math.pi / 48, gt=0, description="rad, to count as at the goal")
        occupancy_x: tuple[float, float] = (0.4, 0.7)
        occupancy_y: tuple[float, float] = (-0.1, 0.2)

    def __init__(self, *, context: TaskContext) -> None:
        self.params = params = context.params
        self.scenario = context.scenario
        self.goal_names = list(context.scenario.objects)
        if params.true_goal not in self.goal_names:
            raise ValueError(f"task.params.true_goal {params.true_goal!r} is not one of the objects {self.goal_names}")
        if context.world is None:
            raise ValueError("the shared control task needs a world: give the spec a workspace or world.arm")
        self.dt = context.dt
        self.ticks = context.ticks
        self.layout = context.world

    def run(self, *, robot: RobotPolicy, human: HumanPolicy, rng: np.random.Generator) -> Rollout:
        p, world = self.params, shared_world(self.layout)
        tracer = world.tracer()
        targets = goal_targets(self.scenario, self.goal_names)
        true = self.goal_names.index(p.true_goal)
        true_targets = poses.prepare_targets(targets[true])
        goal_position = self.scenario.objects[p.true_goal]
        ee, beliefs, events = [], [], []
        reached = False
        who_h, who_r = f"human plugin {type(human).__name__}", f"robot plugin {type(robot).__name__}"
        for tick in range(self.ticks + 1):
            pose = world.ee_pose()
            ee.append(pose[:3, 3].copy())
            tracer.capture()
            if at_goal(pose, true_targets, distance=p.position_tolerance, angle=p.angle_tolerance):
                reached = True
                events.append((tick * self.dt, f"reached {p.true_goal}"))
                break
            if tick == self.ticks:
                break
            user = checked(human.act({"ee_position": pose[:3, 3], "goal_position": goal_position}), who_h, (6,))
            action = robot.act({"ee_pose": pose, "user_twist": user, "goal_targets": targets})
            twist = checked(action.twist, who_r, (6,))
            if action.belief is not None:
                beliefs.append(np.asarray(action.belief, dtype=float))
            world.step_twist(twist, self.dt)
        ee_array = np.array(ee)
        belief = np.array(beliefs) if beliefs else None
        wrong = np.delete(belief, true, axis=1).max() if belief is not None and len(belief) else 0.0
        goals_xy = np.array([self.scenario.objects[n][:2] for n in self.goal_names])
        noise = np.asarray(self.scenario.human.get("waypoint_noise", ()), dtype=float)
        values = {
            "completion_time": (len(ee) - 1) * self.dt if reached else self.ticks * self.dt,
            "min_goal_distance": metrics.min_pairwise_distance(goals_xy),
            "human_variation": float(np.linalg.norm(noise)),
            "max_wrong_goal_probability": float(wrong),
            "robot_path_length": metrics.path_length(ee_array),
        }
        return Rollout(
            dt=self.dt,
            time=np.arange(len(ee)) * self.dt,
            metrics=values,
            trajectories={"robot/ee": ee_array},
            series={f"belief/{name}": belief[:, i] for i, name in enumerate(self.goal_names)}
            if belief is not None
            else {},
            events=events,
            grids={"robot": metrics.occupancy_grid(ee_array, x=p.occupancy_x, y=p.occupancy_y)},
            scene=tracer.finish(),
        )
