"""The built-in arm: a Kinova Mico-like 6-DoF chain of capsules, written as MJCF.

The kinematics are Kinova's published Denavit-Hartenberg table for the Mico (shoulder height
D1 = 0.2755 m, upper arm D2 = 0.29 m, forearm D3 = 0.1233 m, two 60-degree wrist links
D4 = D5 = 0.0741 m, hand D6 = 0.16 m to the tool point, elbow offset e2 = 0.007 m), so the reach is
about 0.7 m and the wrist is the Mico's non-spherical one. The meshes are replaced by capsules, and
the arm stands on a pedestal: the 10 cm base housing with a mounting post under it.

What is ours to choose, and chosen here, is where each joint's zero lies and which way it turns:
joint angle ``q_i`` maps to the DH angle ``theta_i = SIGNS[i] * q_i + OFFSETS[i]``. The offsets
were solved (once, offline) so that the reference start configuration
``(-2.38, -0.43, -0.28, -0.75, 0, 3.55)`` puts the tool point at (0.410, 0.050, 0.960) in the world
with orientation ``R_goal`` (tool z axis, the approach direction, along world +x; tool x along
world +y) when the base is at (0.409, 0.338, 0.795). That pose has the upper arm 71 degrees from
vertical and the elbow bent 71 degrees, elbow up. It is one of the four exact solutions; it was
picked, with the signs, because it matches what the reference's joint ranges imply for the real
Mico: the midpoints of the ranges of joints 2 and 3 are 65 and 74 degrees from the start and are
"upper arm vertical" and "forearm straight", and here they land 6 and 4 degrees from those.

Each body's frame sits at its physical joint centre (slid along the joint axis from the DH
origin), so :meth:`hritest.sim.World.link_poses` gives frames a viewer can draw capsules from.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

# Kinova Mico DH parameters (metres).
D1, D2, D3, D4, D5, D6, E2 = 0.2755, 0.29, 0.1233, 0.0741, 0.0741, 0.16, 0.007
_WRIST = np.pi / 6  # half the 60-degree angle between successive wrist axes
_K = np.sin(_WRIST) / np.sin(2 * _WRIST)  # axis-intersection offset per wrist link, in link lengths
# (alpha, a, d) per joint: Kinova's table for the 6-DoF Mico.
DH = (
    (np.pi / 2, 0.0, D1),
    (np.pi, D2, 0.0),
    (np.pi / 2, 0.0, -E2),
    (2 * _WRIST, 0.0, -(D3 + _K * D4)),
    (2 * _WRIST, 0.0, -(_K * D4 + _K * D5)),
    (np.pi, 0.0, -(_K * D5 + D6)),
)
HOUSING_HEIGHT = 0.1  # the base housing under the shoulder bearing
SIGNS = (1.0, -1.0, 1.0, 1.0, 1.0, 1.0)
OFFSETS = (0.12006, -0.09755, -0.04878, 1.83801, -0.54720, -0.43775)
# Joint centres slid along their axes from the DH origins: the shoulder bearing on top of the
# base housing, the wrist joints at the ends of the forearm and of the two wrist links.
_SHIFTS = (HOUSING_HEIGHT, 0.0, 0.0, -D3, -_K * D4, -_K * D5)

VELOCITY_LIMIT = 0.8378  # rad/s (48 deg/s); the reference's Mico limits are 0.83-0.84
# Joints 2 and 3 are limited as in the reference (rad); the others turn without end.
JOINT_RANGES = (None, (-3.845, 0.704), (-4.104, 0.958), None, None, None)
_RADII = (0.04, 0.035, 0.03, 0.03, 0.03, 0.04)  # capsule radius per link
_FINGER_LENGTH = 0.12  # the hand capsule stops short of the tool point between the fingers


def _rz(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    out = np.eye(4)
    out[:2, :2] = [[c, -s], [s, c]]
    return out


def _dh_constant(alpha: float, a: float, d: float) -> np.ndarray:
    c, s = np.cos(alpha), np.sin(alpha)
    return np.array([[1, 0, 0, a], [0, c, -s, 0], [0, s, c, d], [0, 0, 0, 1.0]])


def _slide(z: float) -> np.ndarray:
    out = np.eye(4)
    out[2, 3] = z
    return out


def _fmt(values: ArrayLike) -> str:
    return " ".join(f"{v:.6g}" if abs(v) > 1e-12 else "0" for v in np.ravel(values))


def _pose_attrs(frame: np.ndarray) -> str:
    return f'pos="{_fmt(frame[:3, 3])}" xyaxes="{_fmt(frame[:3, 0])} {_fmt(frame[:3, 1])}"'


def _link_frames() -> tuple[list[np.ndarray], np.ndarray]:
    """Body frames (joint centres) and the tool frame at q = 0, in the base frame."""
    bodies, dh_frame = [], np.eye(4)
    for (alpha, a, d), offset, shift in zip(DH, OFFSETS, _SHIFTS):
        joint_frame = dh_frame @ _rz(offset)
        bodies.append(joint_frame @ _slide(shift))
        dh_frame = joint_frame @ _dh_constant(alpha, a, d)
    return bodies, dh_frame


def arm_mjcf() -> str:
    """The arm's MJCF, in its base frame (``World`` mounts it at the layout's ``robot_base``).

    Link i's capsule runs from its joint centre to the next one (the hand's from the last wrist
    joint towards the tool point); the ``ee`` site is the tool point with the tool frame. The
    joint velocity limits travel in ``<numeric name="velocity_limits">``, where ``World`` reads
    them (MJCF joints have no velocity-limit attribute).
    """
    frames, tool = _link_frames()
    ends = [frame[:3, 3] for frame in frames[1:]]
    ends.append(frames[-1][:3, 3] + _FINGER_LENGTH * tool[:3, 2])
    starts = [np.array([0.0, 0.0, HOUSING_HEIGHT + _RADII[0]])] + [f[:3, 3] for f in frames[1:]]
    lines, parent = [], np.eye(4)
    for i, frame in enumerate(frames):
        to_local = np.linalg.inv(frame)
        start, end = (to_local @ np.r_[p, 1.0] for p in (starts[i], ends[i]))
        limits = JOINT_RANGES[i]
        joint_range = f' range="{_fmt(limits)}"' if limits else ""
        pad = "  " * (i + 2)
        lines += [
            f'{pad}<body name="link{i + 1}" {_pose_attrs(np.linalg.inv(parent) @ frame)}>',
            f'{pad}  <joint name="joint{i + 1}" axis="0 0 {SIGNS[i]:g}"{joint_range}/>',
            f'{pad}  <geom name="link{i + 1}" type="capsule" size="{_RADII[i]}" '
            f'fromto="{_fmt(start[:3])} {_fmt(end[:3])}"/>',
        ]
        parent = frame
    site = _pose_attrs(np.linalg.inv(parent) @ tool)
    lines.append(f'{"  " * (len(frames) + 2)}<site name="ee" size="0.01" {site}/>')
    lines += [f"{'  ' * (i + 2)}</body>" for i in reversed(range(len(frames)))]
    chain = "\n".join(lines)
    return f"""<mujoco model="mico_like">
  <compiler angle="radian" autolimits="true"/>
  <default><geom rgba="0.25 0.25 0.3 1" contype="1" conaffinity="1"/></default>
  <worldbody>
    <body name="pedestal">
      <geom name="housing" type="cylinder" size="0.045 {HOUSING_HEIGHT / 2}"
            pos="0 0 {HOUSING_HEIGHT / 2}"/>
      <geom name="mount" type="cylinder" size="0.06 0.05" pos="0 0 -0.05"/>
    </body>
{chain}
  </worldbody>
  <contact>
    <!-- The shoulder turns on the housing. Links two apart in the compact wrist (joints 7.4 cm
         apart) always nearly touch as capsules; the real wrist is built not to collide. -->
    <exclude body1="pedestal" body2="link1"/>
    <exclude body1="link3" body2="link5"/>
    <exclude body1="link4" body2="link6"/>
  </contact>
  <custom><numeric name="velocity_limits" data="{_fmt([VELOCITY_LIMIT] * len(DH))}"/></custom>
</mujoco>
"""


ARM_MJCF = arm_mjcf()
