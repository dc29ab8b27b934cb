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
from typing import TYPE_CHECKING, ClassVar

import numpy as np
from hritest_plugins import poses
from hritest_plugins.actions import RobotAction, checked
from hritest_plugins.goals import at_goal, goal_targets
from pydantic import BaseModel, ConfigDict, Field

from hritest import metrics
from hritest.protocols import HumanPolicy, RobotPolicy, Rollout, TaskContext
from hritest.sim import shared_world

if TYPE_CHECKING:
    from hritest.sim import World
    from hritest.sim.world import SceneTracer

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


@dataclass(eq=False)
class _Episode:
    """One run of the task: the world, what is computed once per episode, and what changes."""

    world: World
    goals: np.ndarray  # (n, 3) box centres
    targets: np.ndarray  # (n, 2, 4, 4) the goals' target poses, as the robot observes them
    robot_checks: list[poses.Targets]  # per goal, for the robot's at-goal check
    others: list[np.ndarray]  # per goal, the human's other boxes
    start_q: np.ndarray
    home: np.ndarray  # where the robot resets to; its base joint turns by pi on a replan
    hand: np.ndarray
    hand_pose: np.ndarray
    record: _Record
    h: _Agent = field(default_factory=lambda: _Agent("moving"))
    r: _Agent = field(default_factory=lambda: _Agent("moving"))
    blocked: dict[int, str] = field(default_factory=dict)  # goal -> who works on it


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
        return round(seconds / self.dt)

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
        ep = self._start()
        who_h, who_r = f"human plugin {type(human).__name__}", f"robot plugin {type(robot).__name__}"
        tick = 0
        for tick in range(self.ticks):
            if ep.h.state == ep.r.state == "done":
                break
            t = tick * self.dt
            idle = ep.r.state == "idle"  # the human may set the robot going below; it starts afresh
            velocity = self._human_step(ep, human, who_h, t)
            self._robot_step(ep, robot, who_r, velocity, idle, t)
            ep.hand = ep.hand + velocity * self.dt
        finished = ep.h.state == ep.r.state == "done"
        completion = tick * self.dt if finished else self.ticks * self.dt
        return ep.record.rollout(self, completion, ep.goals, ep.h.wait, ep.r.wait, finished)

    def _start(self) -> _Episode:
        """A reset world and what the episode computes once: per goal, the robot's at-goal check
        and the human's other boxes."""
        world = shared_world(self.layout)
        goals = np.array([self.scenario.objects[n] for n in self.names], dtype=float)
        targets = goal_targets(self.scenario, self.names)
        start_q = world.q
        hand_pose = np.eye(4)
        hand_pose[:3, :3] = poses.GOAL_ROTATION
        return _Episode(
            world=world,
            goals=goals,
            targets=targets,
            robot_checks=[poses.prepare_targets(two) for two in targets],
            others=[np.delete(goals, goal, axis=0) for goal in range(len(goals))],
            start_q=start_q,
            home=start_q.copy(),
            hand=self.start.copy(),
            hand_pose=hand_pose,
            record=_Record(world.tracer()),
        )

    def _human_step(self, ep: _Episode, human: HumanPolicy, who: str, t: float) -> np.ndarray:
        """The human acts, or its state machine moves on; returns the hand's velocity this tick.
        A human that finishes or sets off again may set an idle robot going."""
        p, h, r = self.params, ep.h, ep.r
        velocity = np.zeros(3)
        if h.state == "moving":
            goal = self.order[len(h.done_goals)]
            if math.hypot(*(ep.hand[:2] - ep.goals[goal, :2]).tolist()) < p.position_tolerance:
                h.state, h.goal = "waiting", goal
            else:
                observation = {
                    "hand_position": ep.hand,
                    "goal_position": ep.goals[goal],
                    "other_goals": ep.others[goal],
                }
                velocity = checked(human.act(observation), who, (3,))
        if h.state == "waiting":
            self._wait_or_work(h, "human", p.human_work_time, ep.blocked, ep.record, t)
        elif h.state == "working":
            h.timer -= 1
            if h.timer <= 0:
                del ep.blocked[h.goal]
                h.done_goals.append(h.goal)
                ep.hand = self.start.copy()
                h.state = "done" if len(h.done_goals) == len(self.order) else "resetting"
                ep.record.event(t, f"human finished {self.names[h.goal]}")
        elif h.state == "resetting" and r.state in ("idle", "done"):
            h.state = "moving"
            if r.state == "idle":
                r.state = "moving"
        if h.state == "done" and r.state == "idle":
            r.state = "moving"
        return velocity

    def _robot_step(
        self, ep: _Episode, robot: RobotPolicy, who: str, velocity: np.ndarray, idle: bool, t: float
    ) -> None:
        """The robot acts every tick, so its belief is tracked throughout; it moves when "moving"."""
        pose, action, twist = self._robot_act(ep, robot, who, velocity, idle)
        # A pause entered on this tick (a replan) starts counting down on the next, like work.
        counting = ep.r.state in ("working", "resetting", "replanning")
        if ep.r.state == "moving":
            self._robot_move(ep, pose, action.goal, twist, t)
        if ep.r.state == "waiting":
            self._wait_or_work(ep.r, "robot", self.params.robot_work_time, ep.blocked, ep.record, t)
        elif counting:
            self._robot_count_down(ep, t)

    def _robot_act(
        self, ep: _Episode, robot: RobotPolicy, who: str, velocity: np.ndarray, idle: bool
    ) -> tuple[np.ndarray, RobotAction, np.ndarray]:
        """The robot's action on this tick's observation, and the tick recorded: ``(ee pose,
        action, checked twist)``."""
        pose = ep.world.ee_pose()
        ep.hand_pose = ep.hand_pose.copy()  # a new array each tick: a robot may keep what it is given
        ep.hand_pose[:3, 3] = ep.hand
        action = robot.act(
            {
                "ee_pose": pose,
                "hand_pose": ep.hand_pose,
                "hand_velocity": velocity,
                "goal_targets": ep.targets,
                "visited": tuple(ep.r.done_goals),
                "reset": idle or ep.r.state == "idle",
            }
        )
        twist = checked(action.twist, who, (6,))
        # Wrong-goal probability counts while the human heads for its goal: between goals the
        # belief still (rightly) names the box just finished, which says nothing of inference.
        human_goal = self.order[len(ep.h.done_goals)] if ep.h.state == "moving" else None
        ep.world.set_hand(ep.hand)
        ep.record.tick(pose, ep.hand, ep.h.state, ep.r.state, action.belief, human_goal)
        return pose, action, twist

    def _robot_move(self, ep: _Episode, pose: np.ndarray, heading: int | None, twist: np.ndarray, t: float) -> None:
        """A moving robot stops at an unvisited goal (the one it is ``heading`` for, if it says),
        or takes one tick of ``twist``; a joint limit or a self-collision makes it replan."""
        p, r, world = self.params, ep.r, ep.world
        reached = [
            g
            for g in range(len(ep.goals))
            if g not in r.done_goals
            and (heading is None or heading == g)
            and at_goal(pose, ep.robot_checks[g], distance=p.position_tolerance, angle=p.angle_tolerance)
        ]
        if reached:
            r.state, r.goal = "waiting", reached[0]
            return
        step = world.step_twist(twist, self.dt)
        if (step.limit_reached and np.linalg.norm(twist[:3]) > 1e-4) or world.self_collision():
            ep.home[0] = ep.start_q[0] if ep.home[0] != ep.start_q[0] else _flip(ep.start_q[0])
            world.set_q(ep.home)
            r.state, r.timer = "replanning", self._ticks(p.replan_time)
            ep.record.event(t, "robot replans")
            ep.record.replans += 1

    def _robot_count_down(self, ep: _Episode, t: float) -> None:
        """One tick of work, reset or replanning; at its end the robot finishes its box (and
        resets, unless it was the last), goes idle (or on, once the human is done), or moves."""
        r = ep.r
        r.timer -= 1
        if r.timer > 0:
            return
        if r.state == "working":
            del ep.blocked[r.goal]
            r.done_goals.append(r.goal)
            ep.record.event(t, f"robot finished {self.names[r.goal]}")
            ep.world.set_q(ep.home)
            if len(r.done_goals) == len(ep.goals):
                r.state = "done"
            else:
                r.state, r.timer = "resetting", self._ticks(self.params.robot_reset_time)
        elif r.state == "resetting":
            r.state = "moving" if ep.h.state == "done" else "idle"
        else:
            r.state = "moving"


def _flip(angle: float) -> float:
    """The base joint turned by pi, kept in [-pi, pi]: the arm then faces the other workspace."""
    return angle + math.pi if angle < 0 else angle - math.pi


class _Record:
    """Per-tick arrays of one episode, turned into a :class:`Rollout` at the end."""

    def __init__(self, tracer: SceneTracer) -> None:
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
