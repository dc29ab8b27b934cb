"""Hindsight-optimisation shared autonomy (Javdani et al.): the goal belief and the assisted twists.

A re-implementation of the reference's ``GoalPredictor`` and ``AssistancePolicy``. The robot
treats the human as noisily optimal with a Huber cost-to-go toward each target pose
(:mod:`hritest_plugins.huber`, toward the poses of :mod:`hritest_plugins.poses`); the first-order
approximation of hindsight optimisation makes the assisted action a belief-weighted average of
per-goal straight-line actions. :func:`teleop_step` is a whole robot tick in one compiled call.
"""

from __future__ import annotations

import math
from collections.abc import Collection

import numpy as np
from hritest_plugins.huber import DEFAULT_CONSTANTS, HuberConstants, _goal_actions, _lookahead, _per_goal
from hritest_plugins.poses import Targets, _pose
from numpy.typing import ArrayLike

from hritest.jit import kernel


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
    as_array = lambda v: np.asarray(v, dtype=np.float64)  # noqa: E731 - a one-line local shorthand
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
