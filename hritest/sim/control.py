"""Resolved-rate control: the joint velocities that best realise a world-frame twist."""

from __future__ import annotations

import math

import numpy as np

from hritest.jit import kernel

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
    lo, hi, qdot, status = _bounds_and_solve(jacobian, twist, q, lower, upper, velocity_limits, dt, margin)
    if status == _UNSOLVED:  # exactly singular, or not square: the minimum-norm least-squares solution
        qdot = np.linalg.lstsq(jacobian, twist, rcond=None)[0]
        status = _INSIDE if ((qdot >= lo) & (qdot <= hi)).all() else _OUTSIDE
    if status == _OUTSIDE:
        qdot = _bounded_least_squares(jacobian, twist, lo, hi)
    return _limit_and_scale(jacobian, twist, qdot, velocity_limits, scale_at)


# Statuses of _bounds_and_solve's unbounded solution.
_INSIDE, _OUTSIDE, _UNSOLVED = 0, 1, 2


@kernel
def _bounds_and_solve(
    jacobian: np.ndarray,
    twist: np.ndarray,
    q: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    speeds: np.ndarray,
    dt: float,
    margin: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The velocity bounds, and the unconstrained solution with whether it keeps to them."""
    # Speed allowed towards each limit: none within `margin` of it, and never more than the room
    # left in one tick. Unlimited joints have infinite room.
    n = len(q)
    lo, hi = np.empty(n), np.empty(n)
    for i in range(n):
        down, up = q[i] - lower[i], upper[i] - q[i]
        lo[i] = -min(speeds[i], down / dt) if down > margin else 0.0
        hi[i] = min(speeds[i], up / dt) if up > margin else 0.0
    if jacobian.shape[0] != jacobian.shape[1]:
        return lo, hi, np.zeros(n), _UNSOLVED
    try:
        qdot = np.linalg.solve(jacobian, twist)  # LAPACK's gesv, as np.linalg.solve
    except Exception:
        return lo, hi, np.zeros(n), _UNSOLVED
    for i in range(n):
        if qdot[i] < lo[i] or qdot[i] > hi[i]:
            return lo, hi, qdot, _OUTSIDE
    return lo, hi, qdot, _INSIDE


@kernel
def _limit_and_scale(
    jacobian: np.ndarray, twist: np.ndarray, qdot: np.ndarray, speeds: np.ndarray, scale_at: float
) -> tuple[np.ndarray, bool]:
    """The reference's "joint limit reached" test, then the scaling to ``scale_at`` of the limits."""
    achieved = np.ascontiguousarray(jacobian[:3]) @ qdot
    squares, asked_any = 0.0, False
    for j in range(3):
        if abs(twist[j]) > 1e-12:
            squares += (achieved[j] / twist[j]) ** 2
            asked_any = True
    limit_reached = asked_any and math.sqrt(squares) < LIMIT_RATIO
    peak = 0.0
    for i in range(len(qdot)):
        peak = max(peak, abs(qdot[i]) / speeds[i])
    if peak > scale_at:
        qdot = qdot * (scale_at / peak)
    return qdot, limit_reached


def _bounded_least_squares(jacobian: np.ndarray, twist: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
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
