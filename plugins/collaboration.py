"""The shared workspace collaboration task: the human labels boxes, the robot stamps them.

Follows the paper's appendix "Scenario Simulation" and the reference state machines. Each tick
the human acts, the robot acts, then both move. Neither may work on a box the other is working
on; whoever arrives second waits, and that wait is counted. The human visits the boxes in a
fixed order, working 5 s on each and returning to its start; the robot works 3 s, resets to its
home configuration for 3 s, then stays idle until the human sets off for its next box (the
reference's way of keeping the two in step). When a straight-line motion runs the arm into a
joint limit or itself, the robot "replans": it switches home to the configuration with the base
joint turned by pi (which faces the other workspace) and pauses 3 s. The episode ends when both
have finished every box, or at the time limit.

Two deliberate departures from the reference, both to avoid a lock-up it never hit in practice:
the idle robot may also move once the human has finished, and the robot's last box needs no reset.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np
from hritest_plugins import poses, scene
from pydantic import BaseModel, ConfigDict, Field

from hritest import metrics
from hritest.protocols import HumanPolicy, RobotPolicy, Rollout, TaskContext
from hritest.sim import shared_world

HAND_HEIGHT = 0.96


class _Params(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    goal_order: list[str] | None = Field(None, description="the human's order; default: the objects' order")
    human_start: tuple[float, float] = (0.91, 0.05)
    human_work_time: float = Field(5.0, ge=0)
    robot_work_time: float = Field(3.0, ge=0)
    robot_reset_time: float = Field(3.0, ge=0)
    replan_time: float = Field(3.0, ge=0)
    position_tolerance: float = Field(0.01, gt=0)
    angle_tolerance: float = Field(math.pi / 4, gt=0)
    occupancy_x: tuple[float, float] = (0.1, 2.0)
    occupancy_y: tuple[float, float] = (-0.15, 2.0)


@dataclass
class _Agent:
    """One agent's state machine: its state, a countdown, and accumulated waiting."""

    state: str
    timer: int = 0
    goal: int | None = None
    wait: float = 0.0
    done_goals: list[int] = field(default_factory=list)


class CollaborationTask:
    """Package labelling with a shared workspace: completion time is the objective.

    Human observation: ``hand_position``, ``goal_position``, ``other_goals``. Robot observation:
    ``ee_pose``, ``hand_pose``, ``hand_velocity``, ``goal_targets``, ``visited``, ``reset``.
    """

    kind: ClassVar[str] = "task"
    metrics: ClassVar[tuple[str, ...]] = (
        "completion_time",
        "min_goal_distance",
        "max_wrong_goal_probability",
        "robot_path_length",
        "human_path_length",
        "total_wait_time",
        "human_wait_time",
        "robot_wait_time",
        "replans",
    )
    grids: ClassVar[dict[str, tuple[int, int]]] = {"human": (32, 32), "robot": (32, 32)}
    Params = _Params

    def __init__(self, *, context: TaskContext) -> None:
        self.params = params = context.params
        self.scenario = context.scenario
        self.names = list(context.scenario.objects)
        if context.world is None or not self.names:
            raise ValueError("the collaboration task needs a workspace with objects (the boxes) in its spec")
        order = params.goal_order or self.names
        unknown = sorted(set(order) - set(self.names))
        if unknown or len(set(order)) != len(order):
            raise ValueError(f"task.params.goal_order {order} must list distinct objects of {self.names}")
        self.order = [self.names.index(name) for name in order]
        self.dt = context.dt
        self.ticks = context.ticks
        self.start = np.array([*params.human_start, HAND_HEIGHT])
        self.layout = replace(context.world, hand_start=tuple(self.start))

    def _ticks(self, seconds: float) -> int:
        return int(round(seconds / self.dt))

    def _wait_or_work(
        self, agent: _Agent, who: str, work_time: float, blocked: dict[int, str], record: _Record, t: float
    ) -> None:
        """An agent at its goal starts work once the other is not working there; until then it waits."""
        if agent.goal in blocked:
            agent.wait += self.dt
        else:
            blocked[agent.goal], agent.state, agent.timer = who, "working", self._ticks(work_time)
            record.event(t, f"{who} starts work on {self.names[agent.goal]}")

    def run(self, *, robot: RobotPolicy, human: HumanPolicy, rng: np.random.Generator) -> Rollout:
        p, world = self.params, shared_world(self.layout)
        targets = scene.goal_targets(self.scenario, self.names)
        goals = np.array([self.scenario.objects[n] for n in self.names], dtype=float)
        # Per goal, computed once: the robot's at-goal check and the human's other boxes.
        robot_checks = [poses.prepare_targets(goal_targets) for goal_targets in targets]
        others = [np.delete(goals, goal, axis=0) for goal in range(len(goals))]
        start_q = world.q
        home = start_q.copy()
        hand = self.start.copy()
        hand_pose = np.eye(4)
        hand_pose[:3, :3] = poses.GOAL_ROTATION
        h, r = _Agent("moving"), _Agent("moving")
        blocked: dict[int, str] = {}
        record = _Record(world.tracer())
        who_h, who_r = f"human plugin {type(human).__name__}", f"robot plugin {type(robot).__name__}"
        tick = 0
        for tick in range(self.ticks):
            if h.state == r.state == "done":
                break
            t = tick * self.dt
            idle = r.state == "idle"  # the human may set the robot going below; it starts afresh
            # Human: act, or move its state machine on.
            velocity = np.zeros(3)
            if h.state == "moving":
                goal = self.order[len(h.done_goals)]
                if math.hypot(*(hand[:2] - goals[goal, :2]).tolist()) < p.position_tolerance:
                    h.state, h.goal = "waiting", goal
                else:
                    velocity = scene.checked(
                        human.act({"hand_position": hand, "goal_position": goals[goal], "other_goals": others[goal]}),
                        who_h,
                        (3,),
                    )
            if h.state == "waiting":
                self._wait_or_work(h, "human", p.human_work_time, blocked, record, t)
            elif h.state == "working":
                h.timer -= 1
                if h.timer <= 0:
                    del blocked[h.goal]
                    h.done_goals.append(h.goal)
                    hand = self.start.copy()
                    h.state = "done" if len(h.done_goals) == len(self.order) else "resetting"
                    record.event(t, f"human finished {self.names[h.goal]}")
            elif h.state == "resetting" and r.state in ("idle", "done"):
                h.state = "moving"
                if r.state == "idle":
                    r.state = "moving"
            if h.state == "done" and r.state == "idle":
                r.state = "moving"

            # Robot: it acts every tick, so its belief is tracked throughout; it moves when "moving".
            pose = world.ee_pose()
            hand_pose = hand_pose.copy()  # a new array each tick: a robot may keep what it is given
            hand_pose[:3, 3] = hand
            action = robot.act(
                {
                    "ee_pose": pose,
                    "hand_pose": hand_pose,
                    "hand_velocity": velocity,
                    "goal_targets": targets,
                    "visited": tuple(r.done_goals),
                    "reset": idle or r.state == "idle",
                }
            )
            twist = scene.checked(action.twist, who_r, (6,))
            # Wrong-goal probability counts while the human heads for its goal: between goals the
            # belief still (rightly) names the box just finished, which says nothing of inference.
            human_goal = self.order[len(h.done_goals)] if h.state == "moving" else None
            world.set_hand(hand)
            record.tick(pose, hand, h.state, r.state, action.belief, human_goal)
            # A pause entered on this tick (a replan) starts counting down on the next, like work.
            counting = r.state in ("working", "resetting", "replanning")
            if r.state == "moving":
                reached = [
                    g
                    for g in range(len(goals))
                    if g not in r.done_goals
                    and (action.goal is None or action.goal == g)
                    and scene.at_goal(pose, robot_checks[g], distance=p.position_tolerance, angle=p.angle_tolerance)
                ]
                if reached:
                    r.state, r.goal = "waiting", reached[0]
                else:
                    step = world.step_twist(twist, self.dt)
                    if (step.limit_reached and np.linalg.norm(twist[:3]) > 1e-4) or world.self_collision():
                        home[0] = start_q[0] if home[0] != start_q[0] else _flip(start_q[0])
                        world.set_q(home)
                        r.state, r.timer = "replanning", self._ticks(p.replan_time)
                        record.event(t, "robot replans")
                        record.replans += 1
            if r.state == "waiting":
                self._wait_or_work(r, "robot", p.robot_work_time, blocked, record, t)
            elif counting:
                r.timer -= 1
                if r.timer <= 0:
                    if r.state == "working":
                        del blocked[r.goal]
                        r.done_goals.append(r.goal)
                        record.event(t, f"robot finished {self.names[r.goal]}")
                        world.set_q(home)
                        if len(r.done_goals) == len(goals):
                            r.state = "done"
                        else:
                            r.state, r.timer = "resetting", self._ticks(p.robot_reset_time)
                    elif r.state == "resetting":
                        r.state = "moving" if h.state == "done" else "idle"
                    else:
                        r.state = "moving"
            hand = hand + velocity * self.dt
        finished = h.state == r.state == "done"
        completion = tick * self.dt if finished else self.ticks * self.dt
        return record.rollout(self, completion, goals, h.wait, r.wait, finished)


def _flip(angle: float) -> float:
    """The base joint turned by pi, kept in [-pi, pi]: the arm then faces the other workspace."""
    return angle + math.pi if angle < 0 else angle - math.pi


class _Record:
    """Per-tick arrays of one episode, turned into a :class:`Rollout` at the end."""

    def __init__(self, tracer) -> None:  # noqa: ANN001 - a hritest.sim world tracer
        self.tracer = tracer
        self.ee, self.hand, self.beliefs = [], [], []
        self.human_goals: list[int] = []  # per belief: the human's goal, -1 while it has none
        self.states: dict[str, list[str]] = {"human": [], "robot": []}
        self.events: list[tuple[float, str]] = []
        self.replans = 0

    def event(self, t: float, text: str) -> None:
        self.events.append((t, text))

    def tick(
        self,
        ee_pose: np.ndarray,
        hand: np.ndarray,
        human_state: str,
        robot_state: str,
        belief: np.ndarray | None,
        human_goal: int | None,
    ) -> None:
        self.tracer.capture()
        self.ee.append(ee_pose[:3, 3].copy())
        self.hand.append(hand.copy())
        self.states["human"].append(human_state)
        self.states["robot"].append(robot_state)
        if belief is not None:
            self.beliefs.append(np.asarray(belief, dtype=float))
            self.human_goals.append(-1 if human_goal is None else human_goal)

    def max_wrong_goal_probability(self) -> float:
        """The highest belief in any goal but the human's, over the ticks the human had a goal."""
        goals = np.array(self.human_goals, dtype=int)
        heading = goals >= 0
        if not heading.any():
            return 0.0
        beliefs = np.array(self.beliefs)[heading]
        own = np.arange(beliefs.shape[1]) == goals[heading, None]
        return float(np.where(own, -np.inf, beliefs).max())

    def rollout(
        self,
        task: CollaborationTask,
        completion: float,
        goals: np.ndarray,
        human_wait: float,
        robot_wait: float,
        finished: bool,
    ) -> Rollout:
        p = task.params
        ee, hand = np.array(self.ee), np.array(self.hand)
        values = {
            "completion_time": completion,
            "min_goal_distance": metrics.min_pairwise_distance(goals[:, :2]),
            "max_wrong_goal_probability": self.max_wrong_goal_probability(),
            # Includes the jumps of the robot's resets, as the reference's measure does.
            "robot_path_length": metrics.path_length(ee),
            "human_path_length": metrics.path_length(hand),
            "total_wait_time": human_wait + robot_wait,
            "human_wait_time": human_wait,
            "robot_wait_time": robot_wait,
            "replans": float(self.replans),
        }
        if not finished:
            self.event(completion, "time limit reached")
        beliefs = np.array(self.beliefs)
        return Rollout(
            dt=task.dt,
            time=np.arange(len(ee)) * task.dt,
            metrics=values,
            trajectories={"robot/ee": ee, "human/hand": hand},
            series={f"belief/{name}": beliefs[:, i] for i, name in enumerate(task.names)} if len(beliefs) else {},
            states=self.states,
            events=self.events,
            grids={
                "human": metrics.occupancy_grid(hand, x=p.occupancy_x, y=p.occupancy_y),
                "robot": metrics.occupancy_grid(ee, x=p.occupancy_x, y=p.occupancy_y),
            },
            scene=self.tracer.finish(),
        )
