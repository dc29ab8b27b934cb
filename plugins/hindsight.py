"""Hindsight-optimisation shared autonomy (Javdani et al.): Huber values, belief and twists.

A re-implementation of the reference's ``HuberAssistancePolicy``, ``AssistancePolicyOneGoal``,
``AssistancePolicy`` and ``GoalPredictor``. The robot treats the human as noisily optimal with a
Huber cost-to-go toward each target pose; the first-order approximation of hindsight
optimisation makes the assisted action a belief-weighted average of per-goal straight-line
actions.

Shapes: a pose is a 4x4 homogeneous matrix; ``targets`` may carry leading batch axes
(``(..., 4, 4)``) and every per-target function maps over them. ``goals_targets`` is
``(n_goals, n_targets, 4, 4)``. A twist is ``[vx, vy, vz, wx, wy, wz]`` in the world frame.

Speed: a robot evaluates this every 25 ms tick of every scenario, for a handful of targets (two
per goal), so the per-target math is compiled with numba (a dependency of pyribs already):
interpreted, it was more than half of a teleoperation episode's time, even written on plain
floats. Target poses are prepared once per episode (:func:`prepare_targets`: positions and
orientation quaternions), the rotation from a pose to a target is one quaternion product, and
:func:`lookahead` computes once what the belief update and the actions both need;
:func:`teleop_step` is a whole robot tick in one call. The kernels (``_``-prefixed,
:data:`hritest.compiled.kernel`) take and return plain arrays; the public functions wrap them,
and every function taking ``targets`` accepts 4x4 poses or :class:`Targets`.
"""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import dataclass
from functools import cached_property
from typing import Literal, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from hritest.compiled import kernel

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

    # Cached: read for every target on every tick.
    @cached_property
    def translation(self) -> tuple[float, float, float]:
        """``(a_t, delta_t, c_t)``, the arguments of the translation Huber functions."""
        return self.translation_linear, self.translation_delta, self.translation_constant

    @cached_property
    def rotation(self) -> tuple[float, float, float]:
        """``(a_r, delta_r, c_r)``."""
        return self.rotation_linear, self.rotation_delta, self.rotation_constant

    @cached_property
    def vector(self) -> np.ndarray:
        """Every constant in one array, in the order the kernels read them (``_A_T`` ...)."""
        return np.array(
            [
                self.translation_linear,
                self.translation_delta,
                self.translation_constant,
                self.rotation_linear,
                self.rotation_delta,
                self.rotation_constant,
                self.rotation_multiplier,
                self.robot_translation_cost,
                self.robot_rotation_cost,
                self.action_apply_time,
                self.translation_slowdown,
                self.rotation_slowdown,
            ]
        )


DEFAULT_CONSTANTS = HuberConstants()


# Positions of the constants in HuberConstants.vector, compile-time constants in the kernels.
_A_T, _D_T, _C_T, _A_R, _D_R, _C_R, _K_R, _COST_T, _COST_R, _APPLY, _SLOW_T, _SLOW_R = range(12)


# --- poses and targets -----------------------------------------------------------------------


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


class Targets(NamedTuple):
    """Target poses prepared for the per-tick math (:func:`prepare_targets`).

    Attributes:
        shape: the batch shape of the poses, e.g. ``(n_goals, n_targets)``.
        positions: ``(n, 3)``, one position per target, in C order over ``shape``.
        quaternions: ``(n, 4)``, the unit quaternion ``(x, y, z, w)`` of each target's orientation.
    """

    shape: tuple[int, ...]
    positions: np.ndarray
    quaternions: np.ndarray


def prepare_targets(poses: ArrayLike) -> Targets:
    """:class:`Targets` of ``(..., 4, 4)`` target poses; do it once, not every tick."""
    poses = np.asarray(poses, dtype=np.float64)
    flat = poses.reshape(-1, 4, 4)
    return Targets(
        shape=poses.shape[:-2],
        positions=np.ascontiguousarray(flat[:, :3, 3]),
        quaternions=np.array([_quaternion(np.ascontiguousarray(pose[:3, :3])) for pose in flat]).reshape(-1, 4),
    )


def _prepared(targets: Targets | ArrayLike) -> Targets:
    return targets if isinstance(targets, Targets) else prepare_targets(targets)


def _pose(pose: ArrayLike) -> np.ndarray:
    return np.asarray(pose, dtype=np.float64)


@kernel
def _quaternion(r: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(x, y, z, w)`` of a 3x3 rotation matrix.

    Markley's method, as scipy's ``Rotation.from_matrix``: it builds from the largest of the
    diagonal and the trace, so it stays accurate at every angle, half turns included.
    """
    a, b, c, d, e, f, g, h, i = r[0, 0], r[0, 1], r[0, 2], r[1, 0], r[1, 1], r[1, 2], r[2, 0], r[2, 1], r[2, 2]
    trace = a + e + i
    largest = max(a, e, i, trace)
    if largest == a:
        q = np.array([1.0 - trace + 2.0 * a, d + b, g + c, h - f])
    elif largest == e:
        q = np.array([d + b, 1.0 - trace + 2.0 * e, h + f, c - g])
    elif largest == i:
        q = np.array([g + c, h + f, 1.0 - trace + 2.0 * i, d - b])
    else:
        q = np.array([h - f, c - g, d - b, 1.0 + trace])
    return q / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])


def apply_twist(pose: np.ndarray, twist: ArrayLike, duration: float) -> np.ndarray:
    """The pose reached by holding a world-frame twist for ``duration`` seconds.

    The reference's ``ApplyTwistToTransform``: the position moves by ``v * duration`` and the
    orientation is pre-multiplied (world frame) by the rotation of angle ``|w| * duration``
    about ``w`` (Rodrigues' formula). Unlike the reference, angular speeds below 1e-3 rad/s are
    applied too; user twists carry no rotation, so this only makes the function exact.

    Returns:
        A new 4x4 pose; ``pose`` is not modified.
    """
    return _apply_twist(_pose(pose), np.asarray(twist, dtype=np.float64), float(duration))


@kernel
def _apply_twist(pose: np.ndarray, twist: np.ndarray, duration: float) -> np.ndarray:
    out = pose.copy()
    out[:3, 3] += duration * twist[:3]
    rotvec = duration * twist[3:]
    angle = math.sqrt(rotvec[0] * rotvec[0] + rotvec[1] * rotvec[1] + rotvec[2] * rotvec[2])
    if angle > 0.0:
        x, y, z = rotvec / angle
        k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
        turn = np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)
        out[:3, :3] = turn @ np.ascontiguousarray(pose[:3, :3])
    return out


#: Columns of an offsets array (:func:`offsets`): from a pose to one target per row.
TRANSLATION = slice(0, 3)  #: target position minus the pose's
ROTATION = slice(3, 7)  #: quaternion of the world-frame rotation from the pose's orientation to the target's
DISTANCE = 7  #: translation distance (m)
ANGLE = 8  #: short-way rotation angle (rad, in [0, pi])


def offsets(pose: np.ndarray, targets: Targets | ArrayLike) -> np.ndarray:
    """``(n, 9)``: from ``pose`` to each of ``targets`` (flat, in C order); columns
    :data:`TRANSLATION`, :data:`ROTATION`, :data:`DISTANCE`, :data:`ANGLE`."""
    targets = _prepared(targets)
    return _pose_offsets(_pose(pose), targets.positions, targets.quaternions)


@kernel
def _pose_offsets(pose: np.ndarray, positions: np.ndarray, quaternions: np.ndarray) -> np.ndarray:
    return _offsets(pose[:3, 3].copy(), _quaternion(np.ascontiguousarray(pose[:3, :3])), positions, quaternions)


@kernel
def _offsets(
    position: np.ndarray, orientation: np.ndarray, positions: np.ndarray, quaternions: np.ndarray
) -> np.ndarray:
    x, y, z, w = orientation
    out = np.empty((len(positions), 9))
    for t in range(len(positions)):
        a, b, c, d = quaternions[t]
        # target * conj(orientation), grouped so that equal orientations give exactly the identity.
        rx = (w * a - x * d) + (y * c - z * b)
        ry = (w * b - y * d) + (z * a - x * c)
        rz = (w * c - z * d) + (x * b - y * a)
        rw = x * a + y * b + z * c + w * d
        dx, dy, dz = positions[t, 0] - position[0], positions[t, 1] - position[1], positions[t, 2] - position[2]
        out[t, 0], out[t, 1], out[t, 2] = dx, dy, dz
        out[t, 3], out[t, 4], out[t, 5], out[t, 6] = rx, ry, rz, rw
        out[t, 7] = math.sqrt(dx * dx + dy * dy + dz * dz)
        # 2 atan2(|sin(a/2)|, |cos(a/2)|): accurate at every angle, unlike an arccos.
        out[t, 8] = 2.0 * math.atan2(math.sqrt(rx * rx + ry * ry + rz * rz), abs(rw))
    return out


def within(pose: np.ndarray, targets: Targets | ArrayLike, *, distance: float, angle: float) -> bool:
    """Whether ``pose`` is closer than ``distance`` (m) and ``angle`` (rad) to any of ``targets``."""
    targets = _prepared(targets)
    return _within(_pose(pose), targets.positions, targets.quaternions, float(distance), float(angle))


@kernel
def _within(pose: np.ndarray, positions: np.ndarray, quaternions: np.ndarray, distance: float, angle: float) -> bool:
    towards = _pose_offsets(pose, positions, quaternions)
    for t in range(len(towards)):
        if towards[t, DISTANCE] < distance and towards[t, ANGLE] < angle:
            return True
    return False


def pose_distances(pose: np.ndarray, targets: Targets | ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Translation distance (m) and rotation angle (rad) from ``pose`` to each target."""
    targets = _prepared(targets)
    towards = offsets(pose, targets)
    return towards[:, DISTANCE].reshape(targets.shape), towards[:, ANGLE].reshape(targets.shape)


# --- Huber value, one-step cost and slope ---------------------------------------------------


@kernel
def _huber(x: float, linear: float, delta: float, constant: float) -> float:
    if x <= delta:
        return 0.5 * (linear / delta) * (x * x) + constant * x
    return (linear + constant) * x - 0.5 * linear * delta


@kernel
def _huber_slope(x: float, linear: float, delta: float, constant: float) -> float:
    return linear + constant if x > delta else (linear / delta) * x + constant


@kernel
def _values(towards: np.ndarray, k: np.ndarray) -> np.ndarray:
    """``V_t(d) + k_r V_r(theta)`` per offset."""
    out = np.empty(len(towards))
    for t in range(len(towards)):
        out[t] = _huber(towards[t, DISTANCE], k[_A_T], k[_D_T], k[_C_T]) + k[_K_R] * _huber(
            towards[t, ANGLE], k[_A_R], k[_D_R], k[_C_R]
        )
    return out


@kernel
def _step_cost(towards: np.ndarray, t: int, k: np.ndarray) -> float:
    """Cost of acting for Delta seconds from offset ``t``: Delta times the Huber slope."""
    slope_t = _huber_slope(towards[t, DISTANCE], k[_A_T], k[_D_T], k[_C_T])
    return k[_APPLY] * (slope_t + k[_K_R] * _huber_slope(towards[t, ANGLE], k[_A_R], k[_D_R], k[_C_R]))


def huber_values(towards: np.ndarray, constants: HuberConstants = DEFAULT_CONSTANTS) -> np.ndarray:
    """Huber cost-to-go ``V_t(d) + k_r V_r(theta)`` of each row of an :func:`offsets` array."""
    return _values(towards, constants.vector)


def target_value(
    pose: np.ndarray, target: Targets | ArrayLike, constants: HuberConstants = DEFAULT_CONSTANTS
) -> np.ndarray:
    """Huber cost-to-go ``V = V_t(d) + k_r V_r(theta)`` from ``pose`` to each target.

    The rotation angle is exact (it may go to 0); the reference clips the quaternion's w and so
    never reports less than about 9e-4 rad, a difference far below anything that matters.

    Args:
        pose: 4x4 current pose.
        target: ``(..., 4, 4)`` target poses (or :class:`Targets`).

    Returns:
        ``target.shape[:-2]`` values (a 0-d array for a single target).
    """
    target = _prepared(target)
    return huber_values(offsets(pose, target), constants).reshape(target.shape)


class Lookahead(NamedTuple):
    """Every target's value now and after the user's twist: what belief and action both need.

    Arrays are flat over the targets, in C order over ``shape``.

    Attributes:
        shape: the targets' batch shape.
        values: V at the pose.
        q_values: Q of the twist: one-step cost from the pose plus V after the action.
        after: :func:`offsets` from the pose the twist leads to in ``action_apply_time``.
        values_after: V there.
    """

    shape: tuple[int, ...]
    values: np.ndarray
    q_values: np.ndarray
    after: np.ndarray
    values_after: np.ndarray

    def per_goal(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Goal-level ``(V_g, Q_g, best_target_index)`` for ``(n_goals, n_targets)`` targets.

        A goal's V and Q are those of its target with the minimal V at the pose (the first of
        ties, as numpy's argmin).
        """
        return _per_goal(self.values, self.q_values, self.shape[-1])


@kernel
def _per_goal(values: np.ndarray, q_values: np.ndarray, per: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    best = np.empty(len(values) // per, np.intp)
    for g in range(len(best)):
        best[g] = np.argmin(values[g * per : (g + 1) * per])
    rows = np.arange(len(best)) * per + best
    return values[rows], q_values[rows], best


def lookahead(
    pose: np.ndarray,
    twist: ArrayLike,
    targets: Targets | ArrayLike,
    constants: HuberConstants = DEFAULT_CONSTANTS,
) -> Lookahead:
    """The :class:`Lookahead` of holding ``twist`` at ``pose`` for ``action_apply_time``."""
    targets = _prepared(targets)
    values, q_values, after, values_after = _lookahead(
        _pose(pose), np.asarray(twist, dtype=np.float64), targets.positions, targets.quaternions, constants.vector
    )
    return Lookahead(targets.shape, values, q_values, after, values_after)


@kernel
def _lookahead(
    pose: np.ndarray, twist: np.ndarray, positions: np.ndarray, quaternions: np.ndarray, k: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    orientation = _quaternion(np.ascontiguousarray(pose[:3, :3]))
    now = _offsets(pose[:3, 3].copy(), orientation, positions, quaternions)
    if twist[3] != 0.0 or twist[4] != 0.0 or twist[5] != 0.0:
        after = _pose_offsets(_apply_twist(pose, twist, k[_APPLY]), positions, quaternions)
    else:  # the orientation, so every rotation, stays as it is
        after = _offsets(pose[:3, 3] + k[_APPLY] * twist[:3], orientation, positions, quaternions)
    values_after = _values(after, k)
    q_values = np.empty(len(positions))
    for t in range(len(positions)):
        q_values[t] = _step_cost(now, t, k) + values_after[t]
    return _values(now, k), q_values, after, values_after


def target_q_value(
    pose: np.ndarray,
    twist: ArrayLike,
    target: Targets | ArrayLike,
    constants: HuberConstants = DEFAULT_CONSTANTS,
) -> np.ndarray:
    """Q-value of the user's twist: one-step cost from here plus the value after the action.

    ``Q = C(d_now, theta_now) + V(d_after, theta_after)`` where "after" is the pose reached by
    holding ``twist`` for ``action_apply_time`` (0.1 s). ``Q - V`` is how much worse the user's
    action is than optimal for that target, which is what the belief update penalises.
    """
    look = lookahead(pose, twist, target, constants)
    return look.q_values.reshape(look.shape)


def goal_values(
    pose: np.ndarray,
    twist: ArrayLike,
    goals_targets: Targets | ArrayLike,
    constants: HuberConstants = DEFAULT_CONSTANTS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Goal-level V and Q: those of each goal's target with the minimal V (at ``pose``).

    Args:
        pose: 4x4 pose whose cost-to-go is assessed (the robot EE in teleoperation, the human
            hand in collaboration).
        twist: the user's (or human's) twist.
        goals_targets: ``(n_goals, n_targets, 4, 4)`` (or :class:`Targets`).

    Returns:
        ``(V_g, Q_g, best_target_index)``, each of shape ``(n_goals,)``. Use
        ``goals_targets[np.arange(n_goals), best_target_index]`` to get the targets the
        per-goal actions should head for.
    """
    return lookahead(pose, twist, goals_targets, constants).per_goal()


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
    as_array = lambda v: np.asarray(v, dtype=np.float64)  # noqa: E731
    return _update_belief(as_array(log_belief), as_array(values), as_array(q_values), float(max_prob))


@kernel
def _update_belief(log_belief: np.ndarray, values: np.ndarray, q_values: np.ndarray, max_prob: float) -> np.ndarray:
    log_b = log_belief - (q_values - values)
    log_b -= _log_sum_exp(log_b)
    top = np.argmax(log_b)
    cap = math.log(max_prob)
    if len(log_b) > 1 and log_b[top] > cap:
        excess_each = (math.exp(log_b[top]) - max_prob) / (len(log_b) - 1)
        if excess_each > 0:  # rounding can leave nothing to spread
            spread = math.log(excess_each)
            for g in range(len(log_b)):
                log_b[g] = _log_sum_exp(np.array([log_b[g], spread]))
        log_b[top] = cap
    return log_b


@kernel
def _log_sum_exp(values: np.ndarray) -> float:
    top = values.max()
    return top + math.log(np.exp(values - top).sum())


# --- actions and assisted twists ------------------------------------------------------------


def target_action(
    pose: np.ndarray, target: Targets | ArrayLike, constants: HuberConstants = DEFAULT_CONSTANTS
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
        target: ``(..., 4, 4)`` target poses (or :class:`Targets`).

    Returns:
        ``(..., 6)`` twists; zero components where the pose already coincides with the target.
    """
    target = _prepared(target)
    towards = offsets(pose, target)
    rows = np.arange(len(towards))
    return _actions(towards, rows, constants.vector).reshape((*target.shape, 6))


def goal_actions(
    towards: np.ndarray, target_values: np.ndarray, n_targets: int, constants: HuberConstants = DEFAULT_CONSTANTS
) -> np.ndarray:
    """``(n_goals, 6)``: per goal, the :func:`target_action` toward its target of lowest value.

    Args:
        towards: the :func:`offsets` of every target, goal by goal (``n_targets`` each), from
            the pose the actions start from.
        target_values: their :func:`huber_values`.
        n_targets: targets per goal.
    """
    return _goal_actions(towards, np.asarray(target_values, dtype=np.float64), n_targets, constants.vector)


@kernel
def _goal_actions(towards: np.ndarray, target_values: np.ndarray, per: int, k: np.ndarray) -> np.ndarray:
    best = np.empty(len(towards) // per, np.intp)
    for g in range(len(best)):
        best[g] = g * per + np.argmin(target_values[g * per : (g + 1) * per])
    return _actions(towards, best, k)


@kernel
def _actions(towards: np.ndarray, rows: np.ndarray, k: np.ndarray) -> np.ndarray:
    """The twist toward the target of each of ``rows`` of ``towards``."""
    out = np.zeros((len(rows), 6))
    for i in range(len(rows)):
        o = towards[rows[i]]
        d, angle = o[DISTANCE], o[ANGLE]
        speed = (_huber_slope(d, k[_A_T], k[_D_T], k[_C_T]) * min(1.0, d / k[_SLOW_T])) / k[_COST_T]
        if d > 0:
            for j in range(3):
                out[i, j] = speed * (o[j] / d)
        # About the short-way axis: the quaternion's vector part, turned round where its w < 0.
        omega = k[_K_R] * _huber_slope(angle, k[_A_R], k[_D_R], k[_C_R]) / k[_COST_R]
        omega = math.copysign(omega * min(1.0, angle / k[_SLOW_R]), o[6])
        sin_half = math.sqrt(o[3] * o[3] + o[4] * o[4] + o[5] * o[5])
        if sin_half > 0:
            for j in range(3):
                out[i, 3 + j] = omega * (o[3 + j] / sin_half)
    return out


def belief_weighted_mean(belief: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """``sum_i b(i) a_i / sum b`` of ``(n_goals,)`` beliefs and ``(n_goals, 6)`` actions."""
    return _weighted_mean(np.asarray(belief, dtype=np.float64), np.asarray(actions, dtype=np.float64))


@kernel
def _weighted_mean(belief: np.ndarray, actions: np.ndarray) -> np.ndarray:
    return belief @ np.ascontiguousarray(actions) / belief.sum()


def assisted_twist_teleop(belief: ArrayLike, goal_actions: ArrayLike, user_twist: ArrayLike) -> np.ndarray:
    """Teleoperation twist: belief-weighted mean of per-goal actions plus the user's twist.

    Args:
        belief: ``(n_goals,)`` probabilities (not log).
        goal_actions: ``(n_goals, 6)`` per-goal :func:`target_action` twists.
        user_twist: the direct-teleoperation twist, added unchanged so the user stays in charge.
    """
    return belief_weighted_mean(belief, goal_actions) + np.asarray(user_twist)


def teleop_step(
    pose: np.ndarray,
    user_twist: np.ndarray,
    targets: Targets,
    log_belief: np.ndarray,
    *,
    max_prob: float = 0.99,
    constants: HuberConstants = DEFAULT_CONSTANTS,
) -> tuple[np.ndarray, np.ndarray]:
    """One tick of the teleoperation robot: the new log belief and the per-goal actions.

    The belief update from the user's twist (:func:`lookahead`, :meth:`Lookahead.per_goal`,
    :func:`update_belief`) and the per-goal actions from the pose that twist leads to
    (:func:`goal_actions`, as the reference), in one compiled call: the robot makes it every tick.

    Args:
        targets: ``(n_goals, n_targets)`` prepared :class:`Targets`.
        log_belief: the current ``(n_goals,)`` log belief.
    """
    return _teleop_step(
        _pose(pose),
        np.asarray(user_twist, dtype=np.float64),
        targets.positions,
        targets.quaternions,
        targets.shape[-1],
        np.asarray(log_belief, dtype=np.float64),
        constants.vector,
        float(max_prob),
    )


@kernel
def _teleop_step(
    pose: np.ndarray,
    user: np.ndarray,
    positions: np.ndarray,
    quaternions: np.ndarray,
    per: int,
    log_belief: np.ndarray,
    k: np.ndarray,
    max_prob: float,
) -> tuple[np.ndarray, np.ndarray]:
    values, q_values, after, values_after = _lookahead(pose, user, positions, quaternions, k)
    goal_values, goal_q_values, _ = _per_goal(values, q_values, per)
    return _update_belief(log_belief, goal_values, goal_q_values, max_prob), _goal_actions(after, values_after, per, k)


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
    # Plain Python: a handful of goals, every tick, where numpy's per-call overhead dominates.
    values = [float(v) for v in values]
    visited = {int(v) for v in visited}
    unvisited = [j for j in range(len(values)) if j not in visited]
    mapping = []
    for i in range(len(values)):
        options = [j for j in unvisited if j != i]
        if options:
            mapping.append(min(options, key=values.__getitem__))  # min keeps the first of ties
        else:
            mapping.append(-1 if i in visited else i)
    return np.array(mapping, dtype=np.intp)


def assisted_twist_collab(belief: ArrayLike, goal_actions: ArrayLike, mapping: ArrayLike) -> np.ndarray:
    """Collaboration twist: ``sum_i b(i) a_{m(i)} / sum b``; no user term (the human acts alone).

    The weight of goal ``g'`` is the total belief of human goals mapped to it, so the robot
    heads away from where it thinks the human is going. Human goals mapped to ``-1``
    contribute nothing but still count in the normaliser, as in the reference.

    Args:
        belief: ``(n_goals,)`` probabilities over the human's goal.
        goal_actions: ``(n_goals, 6)`` the robot's per-goal actions.
        mapping: ``(n_goals,)`` from :func:`feasible_goal_mapping`.
    """
    return belief_weighted_mean(np.asarray(belief, dtype=np.float64), mapped_actions(goal_actions, mapping))


def mapped_actions(goal_actions: ArrayLike, mapping: ArrayLike) -> np.ndarray:
    """``(n_goals, 6)``: row i is the action toward goal ``mapping[i]``, zero where that is -1.

    What :func:`assisted_twist_collab` averages. It changes only when the robot moves or
    finishes a goal, so a robot may keep it from one tick to the next.
    """
    rows, none = np.asarray(goal_actions, dtype=np.float64).tolist(), [0.0] * 6
    return np.array([rows[m] if m >= 0 else none for m in np.asarray(mapping).tolist()])


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
