"""Target poses of the goals and the geometry from an end-effector pose to them.

Shapes: a pose is a 4x4 homogeneous matrix; ``targets`` may carry leading batch axes
(``(..., 4, 4)``) and every per-target function maps over them. A twist is
``[vx, vy, vz, wx, wy, wz]`` in the world frame. Target poses are prepared once per episode
(:func:`prepare_targets`: positions and orientation quaternions), so that the rotation from a pose
to a target is one quaternion product. The kernels (``_``-prefixed, :data:`hritest.jit.kernel`)
take and return plain arrays; the public functions wrap them, and every function taking
``targets`` accepts 4x4 poses or :class:`Targets`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from hritest.jit import kernel

#: Orientation of every goal pose: rows ``[[0, 0, 1], [1, 0, 0], [0, 1, 0]]``.
GOAL_ROTATION = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
_YAW_180 = np.diag([-1.0, -1.0, 1.0])


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
    for t in range(len(towards)):  # noqa: SIM110 (numba compiles the loop, not any() over a generator)
        if towards[t, DISTANCE] < distance and towards[t, ANGLE] < angle:
            return True
    return False


def pose_distances(pose: np.ndarray, targets: Targets | ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Translation distance (m) and rotation angle (rad) from ``pose`` to each target."""
    targets = _prepared(targets)
    towards = offsets(pose, targets)
    return towards[:, DISTANCE].reshape(targets.shape), towards[:, ANGLE].reshape(targets.shape)
