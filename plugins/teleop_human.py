"""The simulated teleoperation user: noisy waypoints, the UserBot velocity rule, joystick twist.

The scenario's human parameters are five y-offsets of the waypoints between the start and the
true goal; the simulated user steers the robot end effector toward the current waypoint with a
saturated proportional command (the reference's ``UserBot``), which the joystick mapping turns
into a slow direct-teleoperation twist. Positions may be ``(x, y)`` or ``(x, y, z)``; only x and
y are ever read, because the user only commands planar motion.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from hritest.jit import kernel

#: Number of waypoints from start to goal, both included (5 noisy interior points).
N_WAYPOINTS = 7
#: Below this command norm the user is at its waypoint and moves on to the next.
MIN_COMMAND = 0.005


def waypoints(start_xy: ArrayLike, goal_xy: ArrayLike, noise: ArrayLike) -> np.ndarray:
    """The user's planned path: ``linspace(start, goal, 7)`` with ``noise`` added to interior y.

    Args:
        start_xy: ``(2,)`` start (the EE's initial x-y).
        goal_xy: ``(2,)`` the user's true goal.
        noise: ``(5,)`` y-offsets of waypoints 1..5; endpoints stay exact so the user still
            starts where the robot is and ends at the goal.

    Returns:
        ``(7, 2)`` waypoints.

    Raises:
        ValueError: if ``noise`` does not have one entry per interior waypoint.
    """
    noise = np.asarray(noise, dtype=np.float64)
    if noise.shape != (N_WAYPOINTS - 2,):
        raise ValueError(f"noise must have shape ({N_WAYPOINTS - 2},), got {noise.shape}")
    points = np.linspace(
        np.asarray(start_xy, dtype=np.float64)[:2],
        np.asarray(goal_xy, dtype=np.float64)[:2],
        N_WAYPOINTS,
    )
    points[1:-1, 1] += noise
    return points


def user_velocity(current: ArrayLike, target: ArrayLike, *, gain: float = 10.0, max_speed: float = 0.25) -> np.ndarray:
    """The UserBot command: ``gain * (target - current)`` in x-y, clipped to norm ``max_speed``.

    A saturated proportional controller: full command far from the target, a smooth stop near
    it. z is ignored (the reference zeroes it). This is a joystick-scale command, not a speed:
    :func:`user_twist` (teleoperation) or a speed coefficient (collaboration) turns it into m/s.

    Returns:
        ``(2,)`` command ``(vx, vy)``.
    """
    (tx, ty), (cx, cy) = np.asarray(target, dtype=np.float64)[:2].tolist(), np.asarray(current)[:2].tolist()
    return np.array(_velocity(tx, ty, cx, cy, float(gain), float(max_speed)))


@kernel
def _velocity(tx: float, ty: float, cx: float, cy: float, gain: float, max_speed: float) -> tuple[float, float]:
    vx, vy = gain * (tx - cx), gain * (ty - cy)
    norm = math.hypot(vx, vy)
    if norm > max_speed:
        vx, vy = vx / norm * max_speed, vy / norm * max_speed
    return vx, vy


def next_waypoint_index(
    index: int,
    path: np.ndarray,
    ee_xy: ArrayLike,
    velocity: ArrayLike,
    *,
    min_command: float = MIN_COMMAND,
) -> int:
    """The waypoint to steer toward on the next tick (the reference's advance rule).

    Advance past waypoint ``index`` when the EE has passed it in x (the path runs toward +x,
    and the robot's assistance can carry the EE beyond a waypoint it never touches) or when
    the command toward it has become negligible (the EE is there). The last waypoint is never
    left. The reference calls this rule a hack; it is kept because the paper's scenarios were
    generated with it.

    Args:
        index: current waypoint index.
        path: ``(n, 2)`` waypoints from :func:`waypoints`.
        ee_xy: current EE position.
        velocity: this tick's :func:`user_velocity` toward ``path[index]``.

    Returns:
        ``index + 1`` or ``index``.
    """
    vx, vy = np.asarray(velocity, dtype=np.float64)[:2].tolist()
    return _next_index(
        int(index), np.asarray(path, dtype=np.float64), float(np.asarray(ee_xy)[0]), vx, vy, float(min_command)
    )


@kernel
def _next_index(index: int, path: np.ndarray, ee_x: float, vx: float, vy: float, min_command: float) -> int:
    if index >= len(path) - 1:
        return index
    passed = path[index, 0] < ee_x
    arrived = math.hypot(vx, vy) < min_command
    return index + 1 if passed or arrived else index


def user_twist(velocity: ArrayLike, *, weight: float = 0.2) -> np.ndarray:
    """Direct-teleoperation twist of a user command: ``[w vx, w vy, 0, 0, 0, 0]``.

    ``weight`` is the reference's translation weighting of joystick mode 0, so the user alone
    moves the EE at most ``0.2 * 0.25 = 0.05`` m/s. The collaboration human's "action" seen by
    the robot's belief update is this same twist of its own command.
    """
    vx, vy = np.asarray(velocity, dtype=np.float64)[:2]
    return np.array([weight * vx, weight * vy, 0.0, 0.0, 0.0, 0.0])


def user_step(
    index: int, path: np.ndarray, ee: np.ndarray, *, gain: float, max_speed: float, weight: float
) -> tuple[int, np.ndarray]:
    """One tick of the user: ``(next waypoint index, twist)``.

    :func:`user_velocity` toward ``path[index]``, :func:`next_waypoint_index` and
    :func:`user_twist` in one compiled call, made every tick of a teleoperation episode.
    """
    return _user_step(int(index), path, np.asarray(ee, dtype=np.float64), float(gain), float(max_speed), float(weight))


@kernel
def _user_step(
    index: int, path: np.ndarray, ee: np.ndarray, gain: float, max_speed: float, weight: float
) -> tuple[int, np.ndarray]:
    vx, vy = _velocity(path[index, 0], path[index, 1], ee[0], ee[1], gain, max_speed)
    twist = np.zeros(6)
    twist[0], twist[1] = weight * vx, weight * vy
    return _next_index(index, path, ee[0], vx, vy, MIN_COMMAND), twist
