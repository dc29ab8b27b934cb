"""Hindsight-optimisation shared autonomy (Javdani et al.): Huber values, belief and twists.

Pure-Python re-implementation of the reference's ``HuberAssistancePolicy``,
``AssistancePolicyOneGoal``, ``AssistancePolicy`` and ``GoalPredictor``. The robot treats the
human as noisily optimal with a Huber cost-to-go toward each target pose; the first-order
approximation of hindsight optimisation makes the assisted action a belief-weighted average of
per-goal straight-line actions.

Shapes: a pose is a 4x4 homogeneous matrix; ``targets`` may carry leading batch axes
(``(..., 4, 4)``) and every per-target function maps over them. ``goals_targets`` is
``(n_goals, n_targets, 4, 4)``. A twist is ``[vx, vy, vz, wx, wy, wz]`` in the world frame.

Speed: a robot evaluates this every 25 ms tick of every scenario, for a handful of targets (two
per goal). At that size numpy's overhead of about a microsecond per call is the whole cost, and
plain floats are several times faster, so the per-target math works on floats: target poses are
prepared once (:func:`prepare_targets`: positions and orientation quaternions), the rotation
from a pose to a target is one quaternion product rather than a rotation-matrix conversion, and
:func:`lookahead` computes once what the belief update and the actions both need. The functions
that take and return arrays (:func:`target_value`, :func:`goal_values`, :func:`target_action`,
...) wrap that core; every function taking ``targets`` accepts 4x4 poses or :class:`Targets`.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Literal, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

#: Orientation of every goal pose: rows ``[[0, 0, 1], [1, 0, 0], [0, 1, 0]]``.
GOAL_ROTATION = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
_YAW_180 = np.diag([-1.0, -1.0, 1.0])

Vector = tuple[float, float, float]
Quaternion = tuple[float, float, float, float]  # (x, y, z, w)


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


DEFAULT_CONSTANTS = HuberConstants()


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
        positions: one ``(x, y, z)`` per target, in C order over ``shape``.
        quaternions: one unit quaternion ``(x, y, z, w)`` of the orientation per target.
    """

    shape: tuple[int, ...]
    positions: list[Vector]
    quaternions: list[Quaternion]


def prepare_targets(poses: ArrayLike) -> Targets:
    """:class:`Targets` of ``(..., 4, 4)`` target poses; do it once, not every tick."""
    poses = np.asarray(poses, dtype=np.float64)
    flat = poses.reshape(-1, 4, 4)
    return Targets(
        shape=poses.shape[:-2],
        positions=[tuple(p) for p in flat[:, :3, 3].tolist()],
        quaternions=[_quaternion(r) for r in flat[:, :3, :3].tolist()],
    )


def _prepared(targets: Targets | ArrayLike) -> Targets:
    return targets if isinstance(targets, Targets) else prepare_targets(targets)


def _quaternion(r: list[list[float]]) -> Quaternion:
    """Unit quaternion ``(x, y, z, w)`` of a 3x3 rotation given as nested lists.

    Markley's method, as scipy's ``Rotation.from_matrix``: it builds from the largest of the
    diagonal and the trace, so it stays accurate at every angle, half turns included.
    """
    (a, b, c), (d, e, f), (g, h, i) = r
    trace = a + e + i
    largest = max(a, e, i, trace)
    if largest == a:
        q = (1.0 - trace + 2.0 * a, d + b, g + c, h - f)
    elif largest == e:
        q = (d + b, 1.0 - trace + 2.0 * e, h + f, c - g)
    elif largest == i:
        q = (g + c, h + f, 1.0 - trace + 2.0 * i, d - b)
    else:
        q = (h - f, c - g, d - b, 1.0 + trace)
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm)


def apply_twist(pose: np.ndarray, twist: ArrayLike, duration: float) -> np.ndarray:
    """The pose reached by holding a world-frame twist for ``duration`` seconds.

    The reference's ``ApplyTwistToTransform``: the position moves by ``v * duration`` and the
    orientation is pre-multiplied (world frame) by the rotation of angle ``|w| * duration``
    about ``w`` (Rodrigues' formula). Unlike the reference, angular speeds below 1e-3 rad/s are
    applied too; user twists carry no rotation, so this only makes the function exact.

    Returns:
        A new 4x4 pose; ``pose`` is not modified.
    """
    twist = np.asarray(twist, dtype=np.float64)
    out = np.array(pose, dtype=np.float64)
    out[:3, 3] += duration * twist[:3]
    rotvec = duration * twist[3:]
    angle = math.sqrt(rotvec @ rotvec)
    if angle > 0.0:
        x, y, z = rotvec / angle
        k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
        turn = np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)
        out[:3, :3] = turn @ out[:3, :3]
    return out


class Offset(NamedTuple):
    """From a pose to one target.

    Attributes:
        translation: target position minus the pose's.
        rotation: quaternion of the world-frame rotation taking the pose's orientation to the
            target's.
        distance: translation distance (m).
        angle: short-way rotation angle (rad, in [0, pi]).
    """

    translation: Vector
    rotation: Quaternion
    distance: float
    angle: float


def offsets(pose: np.ndarray, targets: Targets | ArrayLike) -> list[Offset]:
    """The :class:`Offset` from ``pose`` to each of ``targets`` (flat, in C order)."""
    targets = _prepared(targets)
    return _offsets(pose[:3, 3].tolist(), targets, _rotations(_quaternion(pose[:3, :3].tolist()), targets))


def _rotations(orientation: Quaternion, targets: Targets) -> list[tuple[Quaternion, float]]:
    """Per target, the world-frame rotation taking ``orientation`` to the target's, as a
    quaternion ``target * conj(orientation)``, and its angle."""
    x, y, z, w = orientation
    out = []
    for a, b, c, d in targets.quaternions:
        # Grouped so that equal orientations give exactly the identity.
        rx = (w * a - x * d) + (y * c - z * b)
        ry = (w * b - y * d) + (z * a - x * c)
        rz = (w * c - z * d) + (x * b - y * a)
        rw = x * a + y * b + z * c + w * d
        # 2 atan2(|sin(a/2)|, |cos(a/2)|): accurate at every angle, unlike an arccos.
        out.append(((rx, ry, rz, rw), 2.0 * math.atan2(math.hypot(rx, ry, rz), abs(rw))))
    return out


def _offsets(position: Sequence[float], targets: Targets, rotations: list[tuple[Quaternion, float]]) -> list[Offset]:
    px, py, pz = position
    out = []
    for (tx, ty, tz), (rotation, angle) in zip(targets.positions, rotations):
        dx, dy, dz = tx - px, ty - py, tz - pz
        out.append(Offset((dx, dy, dz), rotation, _norm(dx, dy, dz), angle))
    return out


def _norm(dx: float, dy: float, dz: float) -> float:
    return math.sqrt(dx * dx + dy * dy + dz * dz)


def distances(pose: np.ndarray, targets: Targets | ArrayLike) -> list[float]:
    """The :class:`Offset` distances alone (flat, the same numbers): no rotations, so cheaper."""
    px, py, pz = pose[:3, 3].tolist()
    return [_norm(tx - px, ty - py, tz - pz) for tx, ty, tz in _prepared(targets).positions]


def _array(values: list, shape: tuple[int, ...]) -> np.ndarray:
    return np.array(values, dtype=np.float64).reshape(shape + np.shape(values)[1:])


def pose_distances(pose: np.ndarray, targets: Targets | ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Translation distance (m) and rotation angle (rad) from ``pose`` to each target."""
    targets = _prepared(targets)
    towards = offsets(pose, targets)
    return (_array([o.distance for o in towards], targets.shape),
            _array([o.angle for o in towards], targets.shape))


# --- Huber value, one-step cost and slope ---------------------------------------------------


def _huber(x: float, linear: float, delta: float, constant: float) -> float:
    if x <= delta:
        return 0.5 * (linear / delta) * (x * x) + constant * x
    return (linear + constant) * x - 0.5 * linear * delta


def _huber_slope(x: float, linear: float, delta: float, constant: float) -> float:
    return linear + constant if x > delta else (linear / delta) * x + constant


def _value(towards: Offset, c: HuberConstants) -> float:
    """``V_t(d) + k_r V_r(theta)``."""
    return _huber(towards.distance, *c.translation) + c.rotation_multiplier * _huber(towards.angle, *c.rotation)


def _step_cost(towards: Offset, c: HuberConstants) -> float:
    """Cost of acting for Delta seconds from here: Delta times the Huber slope."""
    slope_t = _huber_slope(towards.distance, *c.translation)
    return c.action_apply_time * (slope_t + c.rotation_multiplier * _huber_slope(towards.angle, *c.rotation))


def huber_values(towards: list[Offset], constants: HuberConstants = DEFAULT_CONSTANTS) -> list[float]:
    """Huber cost-to-go ``V_t(d) + k_r V_r(theta)`` of each of the offsets."""
    return [_value(o, constants) for o in towards]


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
    return _array(huber_values(offsets(pose, target), constants), target.shape)


class Lookahead(NamedTuple):
    """Every target's value now and after the user's twist: what belief and action both need.

    Lists are flat over the targets, in C order over ``shape``.

    Attributes:
        shape: the targets' batch shape.
        values: V at the pose.
        q_values: Q of the twist: one-step cost from the pose plus V after the action.
        after: :class:`Offset` from the pose the twist leads to in ``action_apply_time``.
        values_after: V there.
    """

    shape: tuple[int, ...]
    values: list[float]
    q_values: list[float]
    after: list[Offset]
    values_after: list[float]

    def per_goal(self) -> tuple[list[float], list[float], list[int]]:
        """Goal-level ``(V_g, Q_g, best_target_index)`` for ``(n_goals, n_targets)`` targets.

        A goal's V and Q are those of its target with the minimal V at the pose (the first of
        ties, as numpy's argmin).
        """
        per = self.shape[-1]
        best = [_argmin(self.values[g * per:(g + 1) * per]) for g in range(self.shape[0])]
        rows = [g * per + b for g, b in enumerate(best)]
        return [self.values[r] for r in rows], [self.q_values[r] for r in rows], best


def _argmin(values: list[float]) -> int:
    return min(range(len(values)), key=values.__getitem__)


def lookahead(
    pose: np.ndarray,
    twist: ArrayLike,
    targets: Targets | ArrayLike,
    constants: HuberConstants = DEFAULT_CONSTANTS,
) -> Lookahead:
    """The :class:`Lookahead` of holding ``twist`` at ``pose`` for ``action_apply_time``."""
    c, targets = constants, _prepared(targets)
    rotations = _rotations(_quaternion(pose[:3, :3].tolist()), targets)
    position = pose[:3, 3].tolist()
    now = _offsets(position, targets, rotations)
    velocity, spin = np.asarray(twist, dtype=np.float64).reshape(2, 3).tolist()
    if any(spin):
        after = offsets(apply_twist(pose, twist, c.action_apply_time), targets)
    else:  # the orientation, so every rotation, stays as it is
        after = _offsets([p + c.action_apply_time * v for p, v in zip(position, velocity)], targets, rotations)
    values_after = huber_values(after, c)
    return Lookahead(
        shape=targets.shape,
        values=huber_values(now, c),
        q_values=[_step_cost(o, c) + v for o, v in zip(now, values_after)],
        after=after,
        values_after=values_after,
    )


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
    return _array(look.q_values, look.shape)


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
    values, q_values, best = lookahead(pose, twist, goals_targets, constants).per_goal()
    return np.array(values), np.array(q_values), np.array(best, dtype=np.intp)


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
    log_b = [float(b) - (float(q) - float(v)) for b, v, q in zip(log_belief, values, q_values)]
    total = _log_sum_exp(log_b)
    log_b = [b - total for b in log_b]
    top = max(range(len(log_b)), key=log_b.__getitem__)
    cap = math.log(max_prob)
    if len(log_b) > 1 and log_b[top] > cap:
        excess_each = (math.exp(log_b[top]) - max_prob) / (len(log_b) - 1)
        if excess_each > 0:  # rounding can leave nothing to spread
            log_b = [_log_sum_exp([b, math.log(excess_each)]) for b in log_b]
        log_b[top] = cap
    return np.array(log_b)


def _log_sum_exp(values: list[float]) -> float:
    top = max(values)
    return top + math.log(sum(math.exp(v - top) for v in values))


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
    return _array([_action(o, constants) for o in offsets(pose, target)], target.shape)


def goal_actions(towards: list[Offset], target_values: list[float], n_targets: int,
                 constants: HuberConstants = DEFAULT_CONSTANTS) -> np.ndarray:
    """``(n_goals, 6)``: per goal, the :func:`target_action` toward its target of lowest value.

    Args:
        towards: the :class:`Offset` of every target, goal by goal (``n_targets`` each), from
            the pose the actions start from.
        target_values: their :func:`huber_values`.
        n_targets: targets per goal.
    """
    rows = range(0, len(towards), n_targets)
    return np.array([_action(towards[r + _argmin(target_values[r:r + n_targets])], constants) for r in rows])


def _action(towards: Offset, c: HuberConstants) -> list[float]:
    d, angle = towards.distance, towards.angle
    speed = _huber_slope(d, *c.translation) * min(1.0, d / c.translation_slowdown) / c.robot_translation_cost
    linear = [speed * (v / d) for v in towards.translation] if d > 0 else [0.0, 0.0, 0.0]
    # About the short-way axis: the quaternion's vector part, turned round where its w < 0.
    omega = c.rotation_multiplier * _huber_slope(angle, *c.rotation) / c.robot_rotation_cost
    omega = math.copysign(omega * min(1.0, angle / c.rotation_slowdown), towards.rotation[3])
    sin_half = math.hypot(*towards.rotation[:3])
    angular = [omega * (v / sin_half) for v in towards.rotation[:3]] if sin_half > 0 else [0.0, 0.0, 0.0]
    return linear + angular


def belief_weighted_mean(belief: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """``sum_i b(i) a_i / sum b`` of ``(n_goals,)`` beliefs and ``(n_goals, 6)`` actions."""
    return belief @ actions / belief.sum()


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
    return belief_weighted_mean(belief, np.asarray(goal_actions)) + np.asarray(user_twist)


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
