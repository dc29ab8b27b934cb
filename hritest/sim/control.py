"""Resolved-rate control: the joint velocities that best realise a world-frame twist."""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg.lapack import dgesv
from scipy.optimize import lsq_linear

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
    only when that breaks a bound, scipy's ``lsq_linear``. ``dt`` also caps the motion towards a
    limit to what is left of the range in one tick, so the servo's clip never silently truncates a
    commanded velocity (with the default margin and Mico-like speeds it never binds).

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
    # left in one tick. Unlimited joints have infinite room.
    room_down, room_up = q - lower, upper - q
    lo = np.where(room_down > margin, -np.minimum(velocity_limits, room_down / dt), 0.0)
    hi = np.where(room_up > margin, np.minimum(velocity_limits, room_up / dt), 0.0)

    qdot = _least_squares(jacobian, twist)
    if ((qdot < lo) | (qdot > hi)).any():
        qdot = _bounded_least_squares(jacobian, twist, lo, hi)

    # Three components: plain floats are several times faster than numpy here.
    ratios = [
        got / asked
        for got, asked in zip((jacobian[:3] @ qdot).tolist(), twist[:3].tolist())
        if abs(asked) > 1e-12
    ]
    limit_reached = bool(ratios) and math.hypot(*ratios) < LIMIT_RATIO

    peak = (np.abs(qdot) / velocity_limits).max()
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
    # lsq_linear needs lo < hi strictly; a joint with no room either way is pinned at its bound.
    free = lo < hi
    qdot = lo.copy()
    if free.any():
        rest = twist - jacobian[:, ~free] @ qdot[~free]
        qdot[free] = lsq_linear(jacobian[:, free], rest, bounds=(lo[free], hi[free]), method="bvls").x
    return qdot
