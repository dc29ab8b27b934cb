"""Resolved-rate control: the joint velocities that best realise a world-frame twist."""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg.lapack import dgesv

LIMIT_RATIO = 0.6  # the reference's "joint limit reached" threshold on the translation ratio


def twist_to_joint_velocity(
    jacobian: np.ndarray,
    twist: np.ndarray,
    q: np.ndarray,
    *,
    lower: np.ndarray,
    upper: np.ndarray,
    velocity_limits: np.ndarray,
    dt: float = 0.025,
    margin: float = 3e-2,
    scale_at: float = 0.95,
) -> tuple[np.ndarray, bool]:
    """Joint velocities for ``twist`` under velocity and joint limits, as the reference robot did.

    The reference (prpy's ``ComputeJointVelocityFromTwist`` behind ``execute_twist``) minimises
    ``0.5 * ||J qdot - twist||^2`` subject to ``|qdot_i| <= velocity_limits[i]``, allowing no
    motion further into a joint limit once a joint is within ``margin`` rad of it, then scales the
    whole vector down so that no joint runs above ``scale_at`` of its limit. It solved that with
    L-BFGS-B; the problem is a bounded linear least squares, so here it is solved exactly: the
    unconstrained solution first (one 6x6 solve, the common case at teleoperation speeds), and
    only when that breaks a bound, scipy's bounded-variable least squares (:func:`_bvls`). ``dt``
    also caps the motion towards a limit to what is left of the range in one tick, so the servo's
    clip never silently truncates a commanded velocity (with the default margin and Mico-like
    speeds it never binds).

    Args:
        jacobian: (6, n) world-frame Jacobian of the end effector, linear rows first.
        twist: desired ``[vx, vy, vz, wx, wy, wz]`` (m/s, rad/s).
        q: current joint angles (n,).
        lower: lower joint limits, ``-inf`` where a joint turns without end.
        upper: upper joint limits, ``+inf`` likewise.
        velocity_limits: per-joint speed limits (rad/s), positive.
        dt: the tick the velocities will be applied for (s).
        margin: how close to a joint limit (rad) motion towards it stops.
        scale_at: the fraction of the velocity limits the result is scaled down to.

    Returns:
        ``(qdot, limit_reached)``. ``limit_reached`` is the reference's test: the element-wise
        ratio of the achieved translation ``(J qdot)[:3]`` (before the ``scale_at`` scaling, as
        the reference took it from the solver) to the desired ``twist[:3]`` has a norm below 0.6.
        Components the twist leaves at zero are left out of the ratio: the reference divided by
        them too, and the resulting inf or nan made its test false whenever, say, ``vz`` was 0.
        With no translation asked for at all, it is ``False``.
    """
    # Speed allowed towards each limit: none within `margin` of it, and never more than the room
    # left in one tick. Unlimited joints have infinite room. Plain floats: numpy's per-call
    # overhead on six numbers would be most of this function's cost, every tick.
    lo, hi = [], []
    for angle, low, high, speed in zip(q.tolist(), lower.tolist(), upper.tolist(), velocity_limits.tolist()):
        down, up = angle - low, high - angle
        lo.append(-min(speed, down / dt) if down > margin else 0.0)
        hi.append(min(speed, up / dt) if up > margin else 0.0)

    qdot = _least_squares(jacobian, twist)
    if any(v < low or v > high for v, low, high in zip(qdot.tolist(), lo, hi)):
        qdot = _bounded_least_squares(jacobian, twist, np.array(lo), np.array(hi))

    # Three components: plain floats are several times faster than numpy here.
    ratios = [
        got / asked
        for got, asked in zip((jacobian[:3] @ qdot).tolist(), twist[:3].tolist())
        if abs(asked) > 1e-12
    ]
    limit_reached = bool(ratios) and math.hypot(*ratios) < LIMIT_RATIO

    peak = max(abs(v) / speed for v, speed in zip(qdot.tolist(), velocity_limits.tolist()))
    if peak > scale_at:
        qdot = qdot * (scale_at / peak)
    return qdot, limit_reached


def _least_squares(jacobian: np.ndarray, twist: np.ndarray) -> np.ndarray:
    if jacobian.shape[0] == jacobian.shape[1]:
        # LAPACK's gesv directly: the same LU solve as np.linalg.solve at a third of its
        # per-call overhead, which dominates on a 6x6 system.
        *_, qdot, info = dgesv(jacobian, twist)
        if info == 0:
            return qdot
    # Exactly singular, or not square: the minimum-norm least-squares solution.
    return np.linalg.lstsq(jacobian, twist, rcond=None)[0]


def _bounded_least_squares(
    jacobian: np.ndarray, twist: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> np.ndarray:
    # BVLS needs lo < hi strictly; a joint with no room either way is pinned at its bound.
    free = lo < hi
    qdot = lo.copy()
    if free.any():
        rest = twist - jacobian[:, ~free] @ qdot[~free]
        qdot[free] = _bvls(jacobian[:, free], rest, lo[free], hi[free])
    return qdot


def _bvls(a: np.ndarray, b: np.ndarray, lb: np.ndarray, ub: np.ndarray, tol: float = 1e-10) -> np.ndarray:
    """``scipy.optimize.lsq_linear(a, b, (lb, ub), method="bvls", tol=tol).x``, step for step.

    Stark and Parker's bounded-variable least squares as scipy 1.17 implements it: the same
    start, least-squares solves, tie-breaking, tolerance and iteration cap, so the same result
    to the bit. Only the bookkeeping differs, in plain Python on the few joints: scipy's
    generic version spends most of its ~150 us per call on small-array overhead, and a
    collaboration scenario makes about a hundred calls.
    """
    n = a.shape[1]
    x = np.linalg.lstsq(a, b, rcond=-1)[0]
    if ((x >= lb) & (x <= ub)).all():
        return x
    lower, upper = lb.tolist(), ub.tolist()
    # side[i]: -1 or 1 while joint i is held at its lower or upper bound, 0 while free.
    side = [-1 if v <= low else 1 if v >= high else 0 for v, low, high in zip(x.tolist(), lower, upper)]
    x = np.clip(x, lb, ub)
    # Start: solve for the free joints, hold those that leave their box at the bound, repeat.
    while 0 in side:
        free, z = _free_solution(a, b, x, side)
        for i, value in zip(free, z.tolist()):
            if value < lower[i] or value > upper[i]:
                side[i] = -1 if value < lower[i] else 1
                x[i] = lower[i] if value < lower[i] else upper[i]
            else:
                x[i] = value
        if side.count(0) == len(free):
            break
    r = a @ x - b
    cost, gradient = 0.5 * np.dot(r, r), (a.T @ r).tolist()
    for _ in range(n):
        if max(abs(g) if s == 0 else g * s for g, s in zip(gradient, side)) < tol:
            break  # the KKT conditions hold
        side[max(range(n), key=lambda i: gradient[i] * side[i])] = 0  # free the most promising
        while True:  # towards the free solution, stopping where a joint meets its bound
            free, z = _free_solution(a, b, x, side)
            x_free, goal = x[free], z.tolist()
            now = x_free.tolist()
            leaving = [(k, -1, lower[i]) for k, i in enumerate(free) if goal[k] < lower[i]]
            leaving += [(k, 1, upper[i]) for k, i in enumerate(free) if goal[k] > upper[i]]
            if not leaving:
                x[free] = z
                break
            steps = [(bound - now[k]) / (goal[k] - now[k]) for k, _, bound in leaving]
            first = min(range(len(steps)), key=steps.__getitem__)
            x_free *= 1 - steps[first]
            x_free += steps[first] * z
            x[free] = x_free
            k, bound_side, _ = leaving[first]
            side[free[k]] = bound_side
        r = a @ x - b
        cost_new = 0.5 * np.dot(r, r)
        converged = cost - cost_new < tol * cost
        cost, gradient = cost_new, (a.T @ r).tolist()
        if converged:
            break
    return x


def _free_solution(a: np.ndarray, b: np.ndarray, x: np.ndarray, side: list[int]) -> tuple[list[int], np.ndarray]:
    """The free joints, and their least-squares solution with the held ones where they are."""
    free = [i for i, s in enumerate(side) if s == 0]
    held = x * np.array([s != 0 for s in side])
    return free, np.linalg.lstsq(a[:, free], b - a @ held, rcond=None)[0]
