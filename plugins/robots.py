"""Robot policies: hindsight-optimisation assistance, policy blending, and the collaboration robot.

Each class wraps the math of :mod:`hritest_plugins.hindsight` (and of :mod:`~hritest_plugins.huber`,
:mod:`~hritest_plugins.blending`) with the per-episode state (the belief) and reads only the
observation its task gives it.

The goal targets arrive every tick; the robots prepare them (:func:`poses.prepare_targets`)
once per array a task hands them. Tasks build that array once per episode, read-only.
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

import numpy as np
from hritest_plugins import blending, hindsight, huber, poses
from hritest_plugins.actions import RobotAction
from pydantic import BaseModel, ConfigDict, Field


class _Params(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    max_probability: float = Field(0.99, gt=0.5, lt=1.0, description="cap on any goal's belief")


class HindsightRobot:
    """Shared control by hindsight optimisation (Javdani et al. 2015), as in the paper's teleoperation.

    Each tick: update the belief over the user's goal from the user's twist (Boltzmann model,
    log b -= Q - V), then add to the user's twist the belief-weighted average of the per-goal
    straight-line actions, evaluated at the pose the user's twist leads to.

    Observation: ``ee_pose`` (4x4), ``user_twist`` (6,), ``goal_targets`` (goals, targets, 4, 4).
    """

    kind: ClassVar[str] = "robot"
    Params = _Params

    def __init__(self, *, params: _Params, scenario: Any, rng: np.random.Generator) -> None:
        self.params = params
        self.log_belief: np.ndarray | None = None
        self.targets = _PreparedTargets()

    def act(self, observation: dict[str, Any]) -> RobotAction:
        pose, user = observation["ee_pose"], np.asarray(observation["user_twist"], dtype=float)
        targets = self.targets.of(observation["goal_targets"])
        if self.log_belief is None:
            self.log_belief = hindsight.uniform_log_belief(targets.shape[0])
        self.log_belief, actions = hindsight.teleop_step(
            pose, user, targets, self.log_belief, max_prob=self.params.max_probability
        )
        belief = np.exp(self.log_belief)
        return RobotAction(twist=self.combine(belief, actions, user), belief=belief, goal=int(belief.argmax()))

    def combine(self, belief: np.ndarray, actions: np.ndarray, user: np.ndarray) -> np.ndarray:
        """The twist sent to the arm: the belief-weighted average action plus the user's twist."""
        return hindsight.assisted_twist_teleop(belief, actions, user)


class _BlendParams(_Params):
    threshold: float = Field(0.4, ge=0, lt=1, description="top-two belief gap above which the robot assists")
    mode: Literal["aggressive", "timid"] = "aggressive"


class BlendRobot(HindsightRobot):
    """Policy blending (Dragan & Srinivasa 2013): follow the user until confident, then assist.

    Same belief as :class:`HindsightRobot`; only the arbitration differs.
    """

    Params = _BlendParams

    def combine(self, belief: np.ndarray, actions: np.ndarray, user: np.ndarray) -> np.ndarray:
        return blending.blend_twist(belief, actions, user, threshold=self.params.threshold, mode=self.params.mode)


class _CollabParams(_Params):
    inference_twist_scale: float = Field(
        0.4,
        gt=0,
        description="observed hand velocity x this = the twist the belief update assumes; 0.4 = the "
        "reference's 0.2 joystick weight over its 0.5 default human speed",
    )


class CollabRobot:
    """The collaboration robot: infer the human's goal, then work on a different one.

    The belief comes from the human hand's motion under the straight-line Huber model (the
    reference's choice, deliberately not the human's true MDP model). The action is the
    belief-weighted average of twists toward the feasible-goal-set mapping of each candidate
    human goal: the closest goal the robot has not worked on, other than that candidate.

    The reference feeds the belief the human's joystick-scale command times 0.2, independent
    of the human's speed; here the robot sees the hand's actual velocity and scales it by
    ``inference_twist_scale`` (identical at the default speed, and a robot cannot observe a
    human's intent, only motion).

    Observation: ``ee_pose`` (4x4), ``hand_pose`` (4x4), ``hand_velocity`` (3,),
    ``goal_targets`` (goals, targets, 4, 4), ``visited`` (goal indices the robot worked on),
    ``infer`` (bool: update the belief this tick), ``reset`` (bool: back to a uniform belief).
    """

    kind: ClassVar[str] = "robot"
    Params = _CollabParams

    def __init__(self, *, params: _CollabParams, scenario: Any, rng: np.random.Generator) -> None:
        self.params = params
        self.log_belief: np.ndarray | None = None
        self.targets = _PreparedTargets()
        self.hand_values = _LastResult(_hand_values)
        self.plan = _LastResult(_plan)

    def act(self, observation: dict[str, Any]) -> RobotAction:
        targets = self.targets.of(observation["goal_targets"])
        if self.log_belief is None or observation.get("reset", False):
            self.log_belief = hindsight.uniform_log_belief(targets.shape[0])
        if observation.get("infer", True):
            twist = np.zeros(6)
            twist[:3] = self.params.inference_twist_scale * np.asarray(observation["hand_velocity"])
            values, q_values = self.hand_values(targets, np.asarray(observation["hand_pose"], dtype=float), twist)
            self.log_belief = hindsight.update_belief(
                self.log_belief, values, q_values, max_prob=self.params.max_probability
            )
        belief = np.exp(self.log_belief)
        mapping, actions = self.plan(
            targets, np.asarray(observation["ee_pose"], dtype=float), tuple(observation.get("visited", ()))
        )
        twist = hindsight.belief_weighted_mean(belief, actions)
        return RobotAction(twist=twist, belief=belief, goal=mapping[int(belief.argmax())])


def _hand_values(targets: poses.Targets, hand_pose: np.ndarray, twist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Goal-level V and Q of the hand's motion, for the belief update."""
    values, q_values, _ = huber.lookahead(hand_pose, twist, targets).per_goal()
    return values, q_values


def _plan(targets: poses.Targets, ee_pose: np.ndarray, visited: tuple[int, ...]) -> tuple[list, np.ndarray]:
    """The feasible-goal mapping from the robot's values and, per candidate human goal, the
    action toward the goal mapped to it (:func:`hindsight.mapped_actions`)."""
    per = targets.shape[-1]
    towards = poses.offsets(ee_pose, targets)
    values = huber.huber_values(towards)
    mapping = hindsight.feasible_goal_mapping(values.reshape(-1, per).min(axis=1), visited)
    return mapping.tolist(), hindsight.mapped_actions(huber.goal_actions(towards, values, per), mapping)


class _LastResult:
    """A function of targets and more that remembers its last result and arguments.

    In collaboration the arm and the human's hand hold still for most ticks (working, resetting,
    waiting), and the same arguments give the same result: recomputing it would be pure waste.
    Arrays are compared by content. The result is shared, so callers must not modify it.
    """

    def __init__(self, compute: Any) -> None:
        self.compute = compute
        self.targets: poses.Targets | None = None
        self.key: tuple = ()
        self.result: Any = None

    def __call__(self, targets: poses.Targets, *args: Any) -> Any:
        key = tuple(arg.tobytes() if isinstance(arg, np.ndarray) else arg for arg in args)
        if targets is not self.targets or key != self.key:
            self.targets, self.key, self.result = targets, key, self.compute(targets, *args)
        return self.result


class _PreparedTargets:
    """The :class:`poses.Targets` of the last goal-target array seen, prepared once."""

    def __init__(self) -> None:
        self.source: np.ndarray | None = None
        self.prepared: poses.Targets | None = None

    def of(self, targets: np.ndarray) -> poses.Targets:
        if targets is not self.source:
            self.source, self.prepared = targets, poses.prepare_targets(targets)
        return self.prepared
