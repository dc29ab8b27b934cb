"""Robot policies: hindsight-optimisation assistance, policy blending, and the collaboration robot.

Each class wraps the math of :mod:`hritest_plugins.hindsight` with the per-episode state (the
belief) and reads only the observation its task gives it.
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from hritest.protocols import RobotAction
from hritest_plugins import hindsight


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

    def act(self, observation: dict[str, Any]) -> RobotAction:
        pose, user, targets = observation["ee_pose"], observation["user_twist"], observation["goal_targets"]
        if self.log_belief is None:
            self.log_belief = hindsight.uniform_log_belief(len(targets))
        values, q_values, _ = hindsight.goal_values(pose, user, targets)
        self.log_belief = hindsight.update_belief(self.log_belief, values, q_values,
                                                  max_prob=self.params.max_probability)
        belief = np.exp(self.log_belief)
        after = hindsight.apply_twist(pose, user, hindsight.DEFAULT_CONSTANTS.action_apply_time)
        actions = _goal_actions(after, targets)
        return RobotAction(twist=self.combine(belief, actions, user), belief=belief, goal=int(np.argmax(belief)))

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
        return hindsight.blend_twist(belief, actions, user, threshold=self.params.threshold, mode=self.params.mode)


class _CollabParams(_Params):
    inference_twist_scale: float = Field(
        0.4, gt=0,
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

    def act(self, observation: dict[str, Any]) -> RobotAction:
        targets = observation["goal_targets"]
        if self.log_belief is None or observation.get("reset", False):
            self.log_belief = hindsight.uniform_log_belief(len(targets))
        if observation.get("infer", True):
            twist = np.zeros(6)
            twist[:3] = self.params.inference_twist_scale * np.asarray(observation["hand_velocity"])
            values, q_values, _ = hindsight.goal_values(observation["hand_pose"], twist, targets)
            self.log_belief = hindsight.update_belief(self.log_belief, values, q_values,
                                                      max_prob=self.params.max_probability)
        belief = np.exp(self.log_belief)
        pose = observation["ee_pose"]
        robot_values, _, _ = hindsight.goal_values(pose, np.zeros(6), targets)
        mapping = hindsight.feasible_goal_mapping(robot_values, observation.get("visited", ()))
        twist = hindsight.assisted_twist_collab(belief, _goal_actions(pose, targets), mapping)
        return RobotAction(twist=twist, belief=belief, goal=int(mapping[np.argmax(belief)]))


def _goal_actions(pose: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Per goal, the action toward its target of lowest value from ``pose``."""
    _, _, best = hindsight.goal_values(pose, np.zeros(6), targets)
    chosen = targets[np.arange(len(targets)), best]
    return hindsight.target_action(pose, chosen)
