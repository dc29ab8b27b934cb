"""Hindsight-optimisation shared autonomy (Javdani et al.): Huber values, belief and twists.

Pure numpy re-implementation of the reference's ``HuberAssistancePolicy``,
``AssistancePolicyOneGoal``, ``AssistancePolicy`` and ``GoalPredictor``. The robot treats the
human as noisily optimal with a Huber cost-to-go toward each target pose; the first-order
approximation of hindsight optimisation makes the assisted action a belief-weighted average of
per-goal straight-line actions.

Shapes: a pose is a 4x4 homogeneous matrix; ``targets`` may carry leading batch axes
(``(..., 4, 4)``) and every per-target function broadcasts over them. ``goals_targets`` is
``(n_goals, n_targets, 4, 4)``. A twist is ``[vx, vy, vz, wx, wy, wz]`` in the world frame.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

#: Orientation of every goal pose: rows ``[[0, 0, 1], [1, 0, 0], [0, 1, 0]]``.
GOAL_ROTATION = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
_YAW_180 = np.diag([-1.0, -1.0, 1.0])


@dataclass(frozen=True, kw_only=True)
class HuberConstants:
    """Huber cost-to-go constants; defaults are the reference's "assistance always on" values.

    The value of a target is ``V_t(d) + k_r * V_r(theta)`` where each part is quadratic below
    its switch distance and linear above it, with matching value and slope at the switch, so
    the resulting straight-line action is smooth (see :func:`target_action`).

    Attributes:
        translation_linear: a_t, slope gained by the quadratic part up to the switch.
        translation_delta: delta_t (m), where quadratic turns linear.
        translation_constant: c_t, constant slope added everywhere.
        rotation_linear: a_r.
        rotation_delta: delta_r (rad).
        rotation_constant: c_r.
        rotation_multiplier: k_r, weight of the rotation value against translation.
        robot_translation_cost: divides the translation gradient into a speed; 40 caps the
            robot's translational speed at ``(a_t + c_t) / 40 = 0.06125`` m/s.
        robot_rotation_cost: divides the rotation gradient into an angular speed.
        action_apply_time: Delta (s), how long the user's twist is applied to predict the
            pose after the action for Q-values (and, in teleoperation, for the action).
        translation_slowdown: below this distance (m) the translation action shrinks linearly
            to zero; the reference's "hacky part to make it not jumpy".
        rotation_slowdown: same for rotation (rad).
    """

    translation_linear: float = 2.25
    translation_delta: float = 0.07
    translation_constant: float = 0.2
    rotation_linear: float = 0.20
    rotation_delta: float = np.pi / 32.0
    rotation_constant: float = 0.01
    rotation_multiplier: float = 0.07
    robot_translation_cost: float = 40.0
    robot_rotation_cost: float = 0.05
    action_apply_time: float = 0.1
    translation_slowdown: float = 0.02
    rotation_slowdown: float = np.pi / 12.0

    @property
    def max_translation_speed(self) -> float:
        """Speed (m/s) of the translation action far from the target."""
        return (self.translation_linear + self.translation_constant) / self.robot_translation_cost


DEFAULT_CONSTANTS = HuberConstants()


# --- poses ---------------------------------------------------------------------------------


def target_poses(position: ArrayLike) -> np.ndarray:
    """The two target poses of a goal at ``position``: the goal pose and it yawed by 180 deg.

    The gripper can grasp the box from either side, so both count; the robot uses whichever has
    the lower value (:func:`goal_values`).

    Returns:
        ``(2, 4, 4)``: ``[goal pose, Rz(pi) @ goal pose]`` (same position).
    """
    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[0, :3, :3] = GOAL_ROTATION
    poses[1, :3, :3] = _YAW_180 @ GOAL_ROTATION
    poses[:, :3, 3] = np.asarray(position, dtype=np.float64)
    return poses


def apply_twist(pose: np.ndarray, twist: ArrayLike, duration: float) -> np.ndarray:
    """The pose reached by holding a world-frame twist for ``duration`` seconds.

    The reference's ``ApplyTwistToTransform``: the position moves by ``v * duration`` and the
    orientation is pre-multiplied (world frame) by the rotation of angle ``|w| * duration``
    about ``w``. Unlike the reference, angular speeds below 1e-3 rad/s are applied too (the
    rotation-vector form needs no division guard); user twists carry no rotation, so this only
    makes the function exact.

    Returns:
        A new 4x4 pose; ``pose`` is not modified.
    """
    twist = np.asarray(twist, dtype=np.float64)
    out = np.array(pose, dtype=np.float64)
    out[:3, 3] += duration * twist[:3]
    out[:3, :3] = Rotation.from_rotvec(duration * twist[3:]).as_matrix() @ out[:3, :3]
    return out


def _rotation_to_targets(pose: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Short-way rotation vectors (angle in [0, pi]) from the pose to each target orientation."""
    relative = targets[..., :3, :3] @ pose[:3, :3].T  # R_target = relative @ R_pose
    rotvecs = Rotation.from_matrix(relative.reshape(-1, 3, 3)).as_rotvec()
    return rotvecs.reshape(*targets.shape[:-2], 3)


def pose_distances(pose: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translation distance (m) and rotation angle (rad) from ``pose`` to each target."""
    d = np.linalg.norm(targets[..., :3, 3] - pose[:3, 3], axis=-1)
    theta = np.linalg.norm(_rotation_to_targets(pose, targets), axis=-1)
    return d, theta


# --- Huber value, one-step cost and slope ---------------------------------------------------


def _huber(x: np.ndarray, linear: float, delta: float, constant: float) -> np.ndarray:
    quadratic = 0.5 * (linear / delta) * x**2 + constant * x
    return np.where(x <= delta, quadratic, (linear + constant) * x - 0.5 * linear * delta)


def _huber_slope(x: np.ndarray, linear: float, delta: float, constant: float) -> np.ndarray:
    return np.where(x > delta, linear + constant, (linear / delta) * x + constant)


def _value(d: np.ndarray, theta: np.ndarray, c: HuberConstants) -> np.ndarray:
    v_t = _huber(d, c.translation_linear, c.translation_delta, c.translation_constant)
    v_r = _huber(theta, c.rotation_linear, c.rotation_delta, c.rotation_constant)
    return v_t + c.rotation_multiplier * v_r


def _step_cost(d: np.ndarray, theta: np.ndarray, c: HuberConstants) -> np.ndarray:
    """Cost of acting for Delta seconds from distances (d, theta): Delta times the Huber slope."""
    s_t = _huber_slope(d, c.translation_linear, c.translation_delta, c.translation_constant)
    s_r = _huber_slope(theta, c.rotation_linear, c.rotation_delta, c.rotation_constant)
    return c.action_apply_time * (s_t + c.rotation_multiplier * s_r)


def target_value(
    pose: np.ndarray, target: np.ndarray, constants: HuberConstants = DEFAULT_CONSTANTS
) -> np.ndarray:
    """Huber cost-to-go ``V = V_t(d) + k_r V_r(theta)`` from ``pose`` to each target.

    The rotation angle is exact (it may go to 0); the reference clips the quaternion's w and so
    never reports less than about 9e-4 rad, a difference far below anything that matters.

    Args:
        pose: 4x4 current pose.
        target: ``(..., 4, 4)`` target poses.

    Returns:
        ``target.shape[:-2]`` values (a 0-d array for a single target).
    """
    return _value(*pose_distances(pose, np.asarray(target)), constants)


def target_q_value(
    pose: np.ndarray,
    twist: ArrayLike,
    target: np.ndarray,
    constants: HuberConstants = DEFAULT_CONSTANTS,
) -> np.ndarray:
    """Q-value of the user's twist: one-step cost from here plus the value after the action.

    ``Q = C(d_now, theta_now) + V(d_after, theta_after)`` where "after" is the pose reached by
    holding ``twist`` for ``action_apply_time`` (0.1 s). ``Q - V`` is how much worse the user's
    action is than optimal for that target, which is what the belief update penalises.
    """
    target = np.asarray(target)
    return _q_value(pose, twist, pose_distances(pose, target), target, constants)


def _q_value(
    pose: np.ndarray,
    twist: ArrayLike,
    distances_now: tuple[np.ndarray, np.ndarray],
    target: np.ndarray,
    constants: HuberConstants,
) -> np.ndarray:
    """Q given the distances at ``pose`` already computed (:func:`goal_values` shares them)."""
    after = apply_twist(pose, twist, constants.action_apply_time)
    return _step_cost(*distances_now, constants) + _value(*pose_distances(after, target), constants)


def goal_values(
    pose: np.ndarray,
    twist: ArrayLike,
    goals_targets: np.ndarray,
    constants: HuberConstants = DEFAULT_CONSTANTS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Goal-level V and Q: those of each goal's target with the minimal V (at ``pose``).

    Args:
        pose: 4x4 pose whose cost-to-go is assessed (the robot EE in teleoperation, the human
            hand in collaboration).
        twist: the user's (or human's) twist.
        goals_targets: ``(n_goals, n_targets, 4, 4)``.

    Returns:
        ``(V_g, Q_g, best_target_index)``, each of shape ``(n_goals,)``. Use
        ``goals_targets[np.arange(n_goals), best_target_index]`` to get the targets the
        per-goal actions should head for.
    """
    goals_targets = np.asarray(goals_targets)
    now = pose_distances(pose, goals_targets)
    values = _value(*now, constants)
    q_values = _q_value(pose, twist, now, goals_targets, constants)
    best = np.argmin(values, axis=-1)
    rows = np.arange(len(best))
    return values[rows, best], q_values[rows, best], best


# --- belief ---------------------------------------------------------------------------------


def uniform_log_belief(n_goals: int) -> np.ndarray:
    """The prior: log of the uniform distribution over ``n_goals`` goals."""
    return np.full(n_goals, -np.log(n_goals))


def update_belief(
    log_belief: ArrayLike, values: ArrayLike, q_values: ArrayLike, *, max_prob: float = 0.99
) -> np.ndarray:
    """One Bayesian step of the goal belief under a noisily optimal (Boltzmann) user model.

    ``log b(g) -= Q_g - V_g`` (rationality 1, as in the reference), renormalised in log space.
    No goal may exceed ``max_prob``: a belief stuck at 1 could never recover when the user
    changes their mind, so the excess is moved, in probability space and equally, to the others.

    Returns:
        The new normalised log belief (a new array).
    """
    log_b = np.asarray(log_belief, dtype=np.float64) - (
        np.asarray(q_values, dtype=np.float64) - np.asarray(values, dtype=np.float64)
    )
    log_b -= np.logaddexp.reduce(log_b)
    top = int(np.argmax(log_b))
    if log_b.size <= 1 or log_b[top] <= np.log(max_prob):
        return log_b
    excess_each = (np.exp(log_b[top]) - max_prob) / (log_b.size - 1)
    if excess_each > 0:  # rounding can leave nothing to spread
        log_b = np.logaddexp(log_b, np.log(excess_each))
    log_b[top] = np.log(max_prob)
    return log_b


# --- actions and assisted twists ------------------------------------------------------------


def target_action(
    pose: np.ndarray, target: np.ndarray, constants: HuberConstants = DEFAULT_CONSTANTS
) -> np.ndarray:
    """The robot's straight-line twist toward each target: minus the scaled gradient of V.

    Translation: ``-grad_p V_t / robot_translation_cost``, i.e. along ``target - p`` with speed
    ``slope_t(d) / 40`` (at most 0.06125 m/s), shrunk by ``d / 0.02`` inside 2 cm so the arm
    does not chatter at the target. Rotation: about the short-way axis from the current to the
    target orientation with speed ``k_r slope_r(theta) / robot_rotation_cost``, shrunk by
    ``theta / (pi/12)`` below pi/12. The reference returns ``-get_q_derivative()`` with a sign
    flip on the quaternion dot product; the result is the same short-way motion toward the
    target, which is what this returns directly.

    In teleoperation the reference evaluates this at the pose *after* the user's action
    (``apply_twist(pose, user_twist, 0.1)``); in collaboration at the current pose. Pass the
    pose accordingly.

    Args:
        pose: 4x4 pose the action starts from.
        target: ``(..., 4, 4)`` target poses.

    Returns:
        ``(..., 6)`` twists; zero components where the pose already coincides with the target.
    """
    c = constants
    target = np.asarray(target)
    diff = target[..., :3, 3] - pose[:3, 3]
    d = np.linalg.norm(diff, axis=-1, keepdims=True)
    speed = _huber_slope(d, c.translation_linear, c.translation_delta, c.translation_constant)
    speed = speed * np.minimum(1.0, d / c.translation_slowdown) / c.robot_translation_cost
    linear = speed * np.divide(diff, d, out=np.zeros_like(diff), where=d > 0)

    rotvec = _rotation_to_targets(pose, target)
    theta = np.linalg.norm(rotvec, axis=-1, keepdims=True)
    omega = _huber_slope(theta, c.rotation_linear, c.rotation_delta, c.rotation_constant)
    omega = c.rotation_multiplier * omega / c.robot_rotation_cost
    omega = omega * np.minimum(1.0, theta / c.rotation_slowdown)
    angular = omega * np.divide(rotvec, theta, out=np.zeros_like(rotvec), where=theta > 0)
    return np.concatenate([linear, angular], axis=-1)


def _weighted_mean(weights: np.ndarray, actions: np.ndarray) -> np.ndarray:
    return weights @ actions / weights.sum()


def assisted_twist_teleop(
    belief: ArrayLike, goal_actions: ArrayLike, user_twist: ArrayLike
) -> np.ndarray:
    """Teleoperation twist: belief-weighted mean of per-goal actions plus the user's twist.

    Args:
        belief: ``(n_goals,)`` probabilities (not log).
        goal_actions: ``(n_goals, 6)`` per-goal :func:`target_action` twists.
        user_twist: the direct-teleoperation twist, added unchanged so the user stays in charge.
    """
    belief = np.asarray(belief, dtype=np.float64)
    return _weighted_mean(belief, np.asarray(goal_actions)) + np.asarray(user_twist)


def feasible_goal_mapping(values: ArrayLike, visited: Collection[int]) -> np.ndarray:
    """For each candidate human goal i, the goal the robot should work on if the human wants i.

    Pellegrinelli et al.'s feasible goal set: the robot avoids the human's goal and goals it
    already worked on, taking the closest (lowest robot value) unvisited goal ``j != i``. If
    there is none and ``i`` is still unvisited, the robot must share ``i`` (it is the last goal
    left); otherwise ``-1`` (no contribution). Ties go to the lower index, as the reference's
    stable sort. Unlike the reference (a length-3 array), any number of goals works.

    Args:
        values: ``(n_goals,)`` the robot's values ``V_j`` (cost-to-go from the robot EE).
        visited: indices of the goals the robot has worked on.

    Returns:
        ``(n_goals,)`` int array of goal indices, ``-1`` where no goal is feasible.
    """
    values = np.asarray(values, dtype=np.float64)
    n = values.size
    visited_mask = np.isin(np.arange(n), np.asarray(visited, dtype=np.intp))
    feasible = ~visited_mask[None, :] & ~np.eye(n, dtype=bool)
    closest = np.argmin(np.where(feasible, values[None, :], np.inf), axis=1)
    fallback = np.where(visited_mask, -1, np.arange(n))
    return np.where(feasible.any(axis=1), closest, fallback)


def assisted_twist_collab(
    belief: ArrayLike, goal_actions: ArrayLike, mapping: ArrayLike
) -> np.ndarray:
    """Collaboration twist: ``sum_i b(i) a_{m(i)} / sum b``; no user term (the human acts alone).

    The weight of goal ``g'`` is the total belief of human goals mapped to it, so the robot
    heads away from where it thinks the human is going. Human goals mapped to ``-1``
    contribute nothing but still count in the normaliser, as in the reference.

    Args:
        belief: ``(n_goals,)`` probabilities over the human's goal.
        goal_actions: ``(n_goals, 6)`` the robot's per-goal actions.
        mapping: ``(n_goals,)`` from :func:`feasible_goal_mapping`.
    """
    belief = np.asarray(belief, dtype=np.float64)
    mapping = np.asarray(mapping)
    actions = np.asarray(goal_actions, dtype=np.float64)[np.maximum(mapping, 0)]
    actions[mapping < 0] = 0.0
    return _weighted_mean(belief, actions)


def blend_twist(
    belief: ArrayLike,
    goal_actions: ArrayLike,
    user_twist: ArrayLike,
    *,
    threshold: float = 0.4,
    mode: Literal["aggressive", "timid"] = "aggressive",
) -> np.ndarray:
    """Policy blending (Dragan & Srinivasa): follow the user until the prediction is confident.

    Confidence is the gap between the two most likely goals. At or below ``threshold`` the
    user's twist is returned unchanged. Above it the assisted twist toward the most likely goal
    (its action plus the user twist, as in :func:`assisted_twist_teleop` with all belief on
    that goal) takes over: fully ("aggressive"), or ("timid") only in x-y, mixed with the user's
    x-y by ``alpha = min(1.5 (conf - threshold), 0.6)``. The reference writes
    ``1.5 (conf - 0.4)`` capped at 0.6 for conf > 0.8; this is the same for the default
    threshold and keeps alpha continuous for others.

    Raises:
        ValueError: for an unknown ``mode``.
    """
    if mode not in ("aggressive", "timid"):
        raise ValueError(f"mode must be 'aggressive' or 'timid', got {mode!r}")
    belief = np.asarray(belief, dtype=np.float64)
    user_twist = np.asarray(user_twist, dtype=np.float64)
    top_two = np.sort(belief)[-2:]
    confidence = 1.0 if belief.size <= 1 else top_two[1] - top_two[0]
    if confidence <= threshold:
        return user_twist.copy()
    assisted = np.asarray(goal_actions, dtype=np.float64)[np.argmax(belief)] + user_twist
    if mode == "timid":
        alpha = min(1.5 * (confidence - threshold), 0.6)
        assisted[:2] = alpha * assisted[:2] + (1.0 - alpha) * user_twist[:2]
    return assisted
