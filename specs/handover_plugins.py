"""Robot-to-human handover to a moving hand: the task, the robot and the person of ``handover.yaml``.

A 7-DoF arm on a stand holds a parcel out to a standing person. After a reaction delay the person
reaches a hand out to a handover spot in front of them and holds it there; if the robot has not
arrived within their patience, they withdraw the hand, pause, and may try again. The robot drives
its end effector towards the hand (where it will be shortly) while the hand is offered, waits where
it is while it is not, and slows down near the person's head. The handover happens when the end
effector comes within ``handover_distance`` of the hand while the hand is out.

What the three plugins agree on (hritest itself reads neither observations nor actions); all
positions are world-frame ``(3,)`` arrays in metres:

* the person sees ``time`` (s), ``dt`` (s), ``hand_position``, ``hand_rest`` (where the hand hangs
  at rest), ``person_position`` (the body's origin on the floor), ``person_forward`` and
  ``person_right`` (unit vectors: where the person faces, and their right hand side) and
  ``ee_position``; it returns a :class:`HandCommand`;
* the robot sees ``time`` (s), ``dt`` (s), ``ee_position``, ``ee_pose`` (4x4; the tool's z axis is
  where it points), ``hand_position``, ``hand_velocity`` (m/s, the hand's last motion),
  ``person_position``, ``person_forward``, ``head_position`` (the head's centre) and ``arm_mount``
  (where the arm's base stands); it returns an :class:`ArmCommand`.

Observations hand out the task's own arrays: read them, never modify them.

The person model is ``models/handover_room.xml``'s ``person`` body; it faces its -x axis and its
``head`` geom is the head. Both are read from the model file, so moving the head there moves what
the robot keeps clear of.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from functools import cache
from pathlib import Path
from typing import ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from hritest import metrics
from hritest.protocols import HumanPolicy, Observation, RobotPolicy, Rollout, TaskContext
from hritest.scenario import Scenario
from hritest.sim import shared_world

OCCUPANCY_X = (-0.2, 1.8)  # m: the floor area the occupancy grids cover (arm, table and person)
OCCUPANCY_Y = (-1.0, 1.0)


@dataclass(frozen=True)
class HandCommand:
    """What the person does this tick: the hand's velocity (m/s, world frame), whether the hand is
    held out for the parcel (reaching or holding), and the person's state, for the recording."""

    velocity: np.ndarray
    out: bool
    state: str


@dataclass(frozen=True)
class ArmCommand:
    """The robot's world-frame twist ``[vx, vy, vz, wx, wy, wz]`` (m/s, rad/s), the point it heads
    for and its mode (``"approach"``, ``"retreat"``, ``"hold"`` or ``"stalled"``), for the recording."""

    twist: np.ndarray
    target: np.ndarray
    mode: str


@dataclass(frozen=True, kw_only=True)
class PersonModel:
    """Where the person's body origin and head centre are in the model file (the body unturned)."""

    origin: tuple[float, float, float]
    head: tuple[float, float, float]  # in the body's frame


@cache
def person_model(path: str, body: str, head: str) -> PersonModel:
    """Reads the person body's position and its head geom's from the scene MJCF (once per file).

    Raises:
        ValueError: the file has no such body or geom, or turns the body (its frame must be the
            world's: the person faces the body's -x axis and a spec turns it with ``person.yaw``).
    """
    root = ET.parse(path).getroot()
    element = next((e for e in root.iter("body") if e.get("name") == body), None)
    if element is None:
        raise ValueError(f"the world model {path} has no body named {body!r} (task.params.person_body)")
    turned = [a for a in ("quat", "euler", "axisangle", "xyaxes", "zaxis") if a in element.attrib]
    if turned:
        raise ValueError(
            f"body {body!r} of {path} sets {', '.join(turned)}; leave it unturned (it faces its -x "
            "axis) and turn it with a person.yaw parameter instead"
        )
    geom = next((g for g in element.iter("geom") if g.get("name") == head), None)
    if geom is None:
        raise ValueError(f"body {body!r} of {path} has no geom named {head!r} (task.params.head_geom)")

    def xyz(text: str | None) -> tuple[float, float, float]:
        values = [float(v) for v in (text or "0 0 0").split()]
        return values[0], values[1], values[2]

    return PersonModel(origin=xyz(element.get("pos")), head=xyz(geom.get("pos")))


class HandoverTask:
    """The episode: it ends with the handover or at the time limit.

    Metrics: ``handover_time`` (s until the end effector came within ``handover_distance`` of the
    hand while the hand was out; the time limit if it never did), ``reached`` (1 or 0),
    ``min_head_distance`` (m, closest approach of the end effector to the head's centre),
    ``hand_wait_time`` (s the person held the hand still at the handover spot), ``withdrawals``
    (times the person gave up waiting and drew the hand back), ``person_distance`` (m, from the
    arm's mount to the person, on the floor), ``reach_distance`` (m, from the arm's mount to the
    hand where its first reach ended: at the spot, at the handover or at the time limit),
    ``min_ee_hand_distance`` (m) and ``robot_path_length`` (m).
    """

    kind: ClassVar[str] = "task"
    metrics: ClassVar[tuple[str, ...]] = (
        "handover_time",
        "reached",
        "min_head_distance",
        "hand_wait_time",
        "withdrawals",
        "person_distance",
        "reach_distance",
        "min_ee_hand_distance",
        "robot_path_length",
    )
    grids: ClassVar[dict[str, tuple[int, int]]] = {"robot": (32, 32), "human": (32, 32)}

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)
        handover_distance: float = Field(
            0.05, gt=0, le=0.3, description="m between end effector and hand that counts as a handover"
        )
        hand_rest: tuple[float, float, float] = Field(
            (0.04, 0.22, 0.88),
            description="where the hand hangs at rest: m forward, right and up from the person's body origin",
        )
        person_body: str = Field("person", description="the person's body in the world model")
        head_geom: str = Field("head", description="the person's head geom (a child of person_body)")

    def __init__(self, *, context: TaskContext) -> None:
        if context.world is None or context.world.arm is None or context.world.model is None:
            raise ValueError("the handover task needs world.model (the room with the person) and world.arm")
        self.params: HandoverTask.Params = context.params
        self.dt = context.dt
        self.ticks = context.ticks
        p, layout = self.params, context.world
        model = person_model(str(Path(layout.model).resolve()), p.person_body, p.head_geom)
        pose = layout.bodies.get(p.person_body)
        x = model.origin[0] if pose is None or pose.x is None else pose.x
        y = model.origin[1] if pose is None or pose.y is None else pose.y
        z = model.origin[2] if pose is None or pose.z is None else pose.z
        yaw = 0.0 if pose is None else pose.yaw
        c, s = math.cos(yaw), math.sin(yaw)
        self.person = np.array([x, y, z])
        self.forward = np.array([-c, -s, 0.0])  # the body's -x axis, turned by yaw
        self.right = np.array([-s, c, 0.0])  # its +y axis
        hx, hy, hz = model.head
        self.head = self.person + np.array([c * hx - s * hy, s * hx + c * hy, hz])
        fwd, right, up = p.hand_rest
        self.rest = self.person + fwd * self.forward + right * self.right + np.array([0.0, 0.0, up])
        self.mount = np.array(layout.arm.base, dtype=float)
        self.layout = replace(layout, hand_start=tuple(self.rest.tolist()))

    def run(self, *, robot: RobotPolicy, human: HumanPolicy, rng: np.random.Generator) -> Rollout:
        p, dt, world = self.params, self.dt, shared_world(self.layout)
        tracer = world.tracer()
        hand, velocity = self.rest.copy(), np.zeros(3)
        out, human_state, robot_mode = False, "waiting", "hold"
        ee_path, hand_path, distances, head_distances = [], [], [], []
        states: dict[str, list[str]] = {"human": [], "robot": []}
        events: list[tuple[float, str]] = []
        wait_ticks, withdrawals, attempts = 0, 0, 0
        reach_end: np.ndarray | None = None
        reached, tick = False, 0
        for tick in range(self.ticks + 1):
            t = tick * dt
            pose = world.ee_pose()
            ee = pose[:3, 3]
            tracer.capture()
            ee_path.append(ee)
            hand_path.append(hand)
            distance = math.dist(ee, hand)
            distances.append(distance)
            head_distances.append(math.dist(ee, self.head))
            states["human"].append(human_state)
            states["robot"].append(robot_mode)
            if out and distance < p.handover_distance:
                reached = True
                events.append((t, "handover"))
                break
            if tick == self.ticks:
                break
            command = human.act(
                {
                    "time": t,
                    "dt": dt,
                    "hand_position": hand,
                    "hand_rest": self.rest,
                    "person_position": self.person,
                    "person_forward": self.forward,
                    "person_right": self.right,
                    "ee_position": ee,
                }
            )
            new_state = str(command.state)
            if new_state != human_state:
                if new_state == "reaching":
                    attempts += 1
                    events.append((t, f"person reaches out (attempt {attempts})"))
                elif new_state == "holding":
                    events.append((t, "person holds the hand out"))
                elif new_state == "withdrawing":
                    withdrawals += 1
                    events.append((t, "person withdraws the hand"))
                elif new_state == "gave_up":
                    events.append((t, "person gives up"))
                if human_state == "reaching" and reach_end is None:
                    reach_end = hand
            human_state, out = new_state, bool(command.out)
            wait_ticks += human_state == "holding"
            action = robot.act(
                {
                    "time": t,
                    "dt": dt,
                    "ee_position": ee,
                    "ee_pose": pose,
                    "hand_position": hand,
                    "hand_velocity": velocity,
                    "person_position": self.person,
                    "person_forward": self.forward,
                    "head_position": self.head,
                    "arm_mount": self.mount,
                }
            )
            robot_mode = str(action.mode)
            twist = np.asarray(action.twist, dtype=float)
            if twist.any():  # a still arm needs no step (and the controller's solve is most of a tick)
                world.step_twist(twist, dt)
            velocity = np.asarray(command.velocity, dtype=float).reshape(3)
            hand = hand + velocity * dt  # a new array: the ones handed out and recorded stay as they were
            world.set_hand(hand)
        if not reached:
            events.append((tick * dt, "time limit reached"))
        ee_array, hand_array = np.array(ee_path), np.array(hand_path)
        if reach_end is None:  # the first reach never ended before the handover or the time limit
            reach_end = hand_array[-1]
        values = {
            "handover_time": tick * dt if reached else self.ticks * dt,
            "reached": float(reached),
            "min_head_distance": min(head_distances),
            "hand_wait_time": wait_ticks * dt,
            "withdrawals": float(withdrawals),
            "person_distance": float(np.linalg.norm(self.person[:2] - self.mount[:2])),
            "reach_distance": float(np.linalg.norm(reach_end - self.mount)),
            "min_ee_hand_distance": min(distances),
            "robot_path_length": metrics.path_length(ee_array),
        }
        return Rollout(
            dt=dt,
            time=np.arange(len(ee_array)) * dt,
            metrics=values,
            trajectories={"robot/ee": ee_array, "human/hand": hand_array},
            series={"distance/ee_hand": np.array(distances), "distance/ee_head": np.array(head_distances)},
            states=states,
            events=events,
            grids={
                "robot": metrics.occupancy_grid(ee_array, x=OCCUPANCY_X, y=OCCUPANCY_Y),
                "human": metrics.occupancy_grid(hand_array, x=OCCUPANCY_X, y=OCCUPANCY_Y),
            },
            scene=tracer.finish(),
        )


class ReachingRobot:
    """Drives the end effector to where the offered hand will be, at a capped speed.

    While the hand is offered (more than ``offer_distance`` in front of the person's body origin
    and not drawn back towards the body faster than ``withdraw_speed``) the target is the hand
    plus its velocity times ``lookahead``, kept inside the arm's workspace: within ``reach`` of the
    shoulder (``shoulder_height`` above the mount) and at least ``min_radius`` from the mount's
    vertical axis, so the arm never strains against its joint limits for a hand it cannot get to;
    it waits at the edge instead. While the hand is not offered the robot goes back to where its
    end effector started (``retreat``, out of the person's space: each reach starts afresh) or
    holds still where it is (``retreat: false``). The speed is ``gain`` times the distance to the
    target, at most ``max_speed``; moving towards the head it slows down linearly from
    ``head_stop + head_slow`` to a stop at ``head_stop`` from the head's centre (moving away it does
    not slow). The tool keeps its pitch and roll and turns about the vertical to face the target as
    seen from the mount (``turn_gain``, at most ``max_turn``). When the hand is still and a tick
    brought the end effector less than ``stall_progress`` of the step it asked for closer to the
    target (a joint limit, a stretched arm), the arm has stalled: it waits (mode ``"stalled"``)
    until the target moves ``stall_resume`` away.
    """

    kind: ClassVar[str] = "robot"

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)
        max_speed: float = Field(0.25, gt=0, le=1.0, description="m/s: the end effector's speed cap")
        gain: float = Field(2.5, gt=0, description="1/s: speed per metre of distance to the target")
        lookahead: float = Field(0.25, ge=0, le=2.0, description="s the hand's motion is extrapolated")
        offer_distance: float = Field(
            0.15, gt=0, description="m in front of the person's body a hand counts as offered"
        )
        withdraw_speed: float = Field(
            0.05, ge=0, description="m/s towards the body at which a hand counts as drawn back"
        )
        retreat: bool = Field(True, description="go back to the start while no hand is offered (else hold still)")
        head_stop: float = Field(0.2, ge=0, description="m from the head's centre where approaching stops")
        head_slow: float = Field(0.25, gt=0, description="m before head_stop over which the robot slows")
        shoulder_height: float = Field(0.3, ge=0, description="m of the shoulder above the arm's mount")
        reach: float = Field(0.78, gt=0, description="m from the shoulder the end effector is sent at most")
        min_radius: float = Field(0.38, ge=0, description="m from the mount's axis the end effector keeps at least")
        turn_gain: float = Field(2.0, ge=0, description="1/s: tool yaw rate per radian it is turned off the target")
        max_turn: float = Field(0.8, gt=0, description="rad/s: the tool's yaw rate cap")
        settled: float = Field(0.005, ge=0, description="m from the target at which the robot stops moving")
        stall_progress: float = Field(
            0.25,
            ge=0,
            le=1,
            description="fraction of the step asked that, not made good towards a still hand, stalls the arm",
        )
        stall_resume: float = Field(0.02, gt=0, description="m the target must move for a stalled arm to go on")

    def __init__(self, *, params: ReachingRobot.Params, scenario: Scenario, rng: np.random.Generator) -> None:
        self.params = params
        self.stalled_at: np.ndarray | None = None  # the target the arm could not get closer to
        self.last: tuple[float, float] | None = None  # (distance to the target, step asked) last tick
        self.home: np.ndarray | None = None  # where the end effector started

    def act(self, observation: Observation) -> ArmCommand:
        p = self.params
        ee = observation["ee_position"]
        hand = observation["hand_position"]
        person = observation["person_position"]
        forward, velocity = observation["person_forward"], observation["hand_velocity"]
        if self.home is None:
            self.home = np.array(ee, dtype=float)
        in_front = (hand[0] - person[0]) * forward[0] + (hand[1] - person[1]) * forward[1] > p.offer_distance
        drawn_back = velocity[0] * forward[0] + velocity[1] * forward[1] < -p.withdraw_speed
        hand_still = not velocity.any()
        if not in_front or drawn_back:
            self.last, self.stalled_at = None, None
            if not p.retreat:
                return ArmCommand(twist=np.zeros(6), target=ee, mode="hold")
            target, mode = self.home, "retreat"
        else:
            target, mode = self._inside(hand + p.lookahead * velocity, observation["arm_mount"]), "approach"
        if mode == "approach" and self.stalled_at is not None:
            if hand_still and math.dist(target, self.stalled_at) < p.stall_resume:
                return ArmCommand(twist=np.zeros(6), target=target, mode="stalled")
            self.stalled_at = None
        error = target - ee
        distance = math.sqrt(float(error @ error))
        if distance <= p.settled:  # close enough: stand still (a still arm costs the task no step)
            self.last = None
            return ArmCommand(twist=np.zeros(6), target=target, mode="hold" if mode == "retreat" else mode)
        if mode == "approach" and hand_still and self.last is not None:
            last_distance, last_step = self.last
            if last_distance - distance < p.stall_progress * last_step:
                self.stalled_at, self.last = target, None
                return ArmCommand(twist=np.zeros(6), target=target, mode="stalled")
        direction = error / distance
        speed = min(p.max_speed, p.gain * distance)
        to_head = observation["head_position"] - ee
        if float(direction @ to_head) > 0.0:  # closing in on the head
            head_distance = math.sqrt(float(to_head @ to_head))
            speed *= min(max((head_distance - p.head_stop) / p.head_slow, 0.0), 1.0)
        watching = mode == "approach" and hand_still and speed > 0.0  # for a stall on the next tick
        self.last = (distance, speed * float(observation["dt"])) if watching else None
        twist = np.zeros(6)
        twist[:3] = direction * speed
        # Turn the tool about the vertical towards the target, as seen from the mount: it then
        # reaches along its own axis instead of sideways.
        mount, tool = observation["arm_mount"], observation["ee_pose"][:3, 2]
        heading = math.atan2(target[1] - mount[1], target[0] - mount[0])
        error_yaw = math.remainder(heading - math.atan2(tool[1], tool[0]), math.tau)
        twist[5] = min(max(p.turn_gain * error_yaw, -p.max_turn), p.max_turn)
        return ArmCommand(twist=twist, target=target, mode=mode)

    def _inside(self, target: np.ndarray, mount: np.ndarray) -> np.ndarray:
        """``target`` moved into the workspace: the reach sphere, outside the inner cylinder."""
        p = self.params
        shoulder = mount + np.array([0.0, 0.0, p.shoulder_height])
        offset = target - shoulder
        length = math.sqrt(float(offset @ offset))
        if length > p.reach:
            offset = offset * (p.reach / length)
        radius = math.hypot(offset[0], offset[1])
        if 0.0 < radius < p.min_radius:
            offset[:2] *= p.min_radius / radius
        return shoulder + offset


class ReachingPerson:
    """Reaches out after a reaction delay, holds the hand out for a while, withdraws and retries.

    States: ``waiting`` (the reaction delay, from the start), ``reaching`` (to the handover spot,
    ``spot_forward`` in front of the body origin, ``spot_right`` to its right, ``spot_height`` above
    the floor, jittered per attempt by ``jitter`` m), ``holding`` (at the spot; after ``patience`` s
    there), ``withdrawing`` (back to rest), ``pausing`` (``retry_pause`` s) and, after
    ``max_attempts`` reaches, ``gave_up``. The hand moves straight at ``reach_speed`` (times a
    factor of 0.9 to 1.1 drawn per attempt) and lands exactly on its target.
    """

    kind: ClassVar[str] = "human"

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)
        reaction_delay: float = Field(0.5, ge=0, le=10, description="s before the person first reaches out")
        patience: float = Field(
            3.0, gt=0, le=30, description="s the hand is held out at the spot before it is withdrawn"
        )
        reach_speed: float = Field(0.5, gt=0, le=2.0, description="m/s of the hand")
        spot_forward: float = Field(0.4, ge=0.1, le=0.7, description="m in front of the body the hand is held")
        spot_right: float = Field(0.1, ge=-0.4, le=0.4, description="m to the person's right of the body axis")
        spot_height: float = Field(1.1, ge=0.6, le=1.7, description="m above the floor")
        retry_pause: float = Field(1.0, ge=0, description="s at rest between a withdrawal and the next reach")
        max_attempts: int = Field(3, ge=1, description="reaches before the person gives up")
        jitter: float = Field(0.015, ge=0, le=0.1, description="m, standard deviation of the spot per attempt")

    def __init__(self, *, params: ReachingPerson.Params, scenario: Scenario, rng: np.random.Generator) -> None:
        self.params = params
        self.rng = rng
        self.state = "waiting"
        self.since = 0.0  # when the current state began (s)
        self.attempts = 0
        self.target: np.ndarray | None = None
        self.speed = params.reach_speed

    def act(self, observation: Observation) -> HandCommand:
        p, t = self.params, float(observation["time"])
        hand = observation["hand_position"]
        if self.state == "waiting" and t >= p.reaction_delay - 1e-9:
            self._reach(observation, t)
        elif self.state == "reaching" and math.dist(hand, self.target) < 1e-6:
            self.state, self.since = "holding", t
        elif self.state == "holding" and t - self.since >= p.patience - 1e-9:
            self.state, self.since, self.target = "withdrawing", t, observation["hand_rest"]
        elif self.state == "withdrawing" and math.dist(hand, self.target) < 1e-6:
            self.state, self.since = ("pausing", t) if self.attempts < p.max_attempts else ("gave_up", t)
        elif self.state == "pausing" and t - self.since >= p.retry_pause - 1e-9:
            self._reach(observation, t)
        velocity = np.zeros(3)
        if self.state in ("reaching", "withdrawing"):
            error = self.target - hand
            distance = math.dist(self.target, hand)
            if distance > 0.0:
                step = min(self.speed, distance / float(observation["dt"]))
                velocity = error / distance * step
        return HandCommand(velocity=velocity, out=self.state in ("reaching", "holding"), state=self.state)

    def _reach(self, observation: Observation, t: float) -> None:
        p = self.params
        spot = (
            observation["person_position"]
            + p.spot_forward * observation["person_forward"]
            + p.spot_right * observation["person_right"]
        )
        spot = np.array([spot[0], spot[1], p.spot_height]) + self.rng.normal(0.0, p.jitter, 3)
        self.attempts += 1
        self.state, self.since, self.target = "reaching", t, spot
        self.speed = p.reach_speed * self.rng.uniform(0.9, 1.1)
