"""The Huber cost-to-go toward a target pose (the reference's ``HuberAssistancePolicy`` and
``AssistancePolicyOneGoal``): its value, the Q-value of a user's twist, and the straight-line action
that descends it.

``goals_targets`` is ``(n_goals, n_targets, 4, 4)`` (see :mod:`hritest_plugins.poses` for shapes).
:func:`lookahead` computes once what the belief update and the actions both need.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np
from hritest_plugins.poses import (
    ANGLE,
    DISTANCE,
    Targets,
    _apply_twist,
    _offsets,
    _pose,
    _pose_offsets,
    _prepared,
    _quaternion,
    offsets,
)
from numpy.typing import ArrayLike

from hritest.jit import kernel


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
