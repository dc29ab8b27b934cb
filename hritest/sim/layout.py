"""What a MuJoCo world contains and what a task did in it, as plain data (no ``mujoco`` import).

A :class:`WorldLayout` is built by the domain from the spec's ``world`` and ``workspace``
sections and the scenario's bound values; a task hands it to :func:`hritest.sim.shared_world`.
A :class:`SceneTrace` is what a task returns in ``Rollout.scene`` so that recordings draw the
world the task actually simulated, not one rebuilt from the spec.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

ROBOT_BASE = (0.409, 0.338, 0.795)
START_CONFIG = (-2.38, -0.43, -0.28, -0.75, 0.0, 3.55)
BODY_ATTRIBUTES = ("x", "y", "z", "yaw")  # what a parameter may set on a named body of the world
ARM_ATTRIBUTES = (*BODY_ATTRIBUTES, "start")  # and on the arm's mount


@dataclass(frozen=True, kw_only=True)
class Box:
    """An axis-aligned box: a table, a workspace region or a goal object."""

    name: str
    center: tuple[float, float, float]
    half_size: tuple[float, float, float]
    rgba: tuple[float, float, float, float] = (0.6, 0.6, 0.6, 1.0)

    def __post_init__(self) -> None:
        for name, size in (("center", 3), ("half_size", 3), ("rgba", 4)):
            value = tuple(float(v) for v in getattr(self, name))
            if len(value) != size:
                raise ValueError(f"Box {self.name!r}: {name} needs {size} numbers, got {value}")
            object.__setattr__(self, name, value)


@dataclass(frozen=True, kw_only=True)
class BodyPose:
    """Where a named body of the world model goes: ``None`` keeps the model file's value.

    ``yaw`` (rad, about world z) turns the body from its orientation in the file.
    """

    x: float | None = None
    y: float | None = None
    z: float | None = None
    yaw: float = 0.0


@dataclass(frozen=True, kw_only=True)
class ArmMount:
    """A robot arm and where it stands.

    ``mjcf`` is the path of an arm MJCF (``None``: the built-in Mico-like 6-DoF arm, see
    :mod:`hritest.sim.arm`). Its hinge joints, in file order, are the arm's joints, ``ee_site``
    names its tool site, and ``<custom><numeric name="velocity_limits" data="..."/></custom>``
    gives one joint speed limit (rad/s) per hinge. The arm file's world frame is placed at
    ``base`` turned by ``yaw`` about z. ``start`` is the joint configuration at reset (``None``:
    the built-in arm's reference start, or the arm file's ``qpos0`` for a user's arm).
    """

    mjcf: str | None = None
    ee_site: str = "ee"
    base: tuple[float, float, float] = ROBOT_BASE
    yaw: float = 0.0
    start: tuple[float, ...] | None = None


@dataclass(frozen=True, kw_only=True)
class WorldLayout:
    """What a world contains; :class:`hritest.sim.World` compiles it once per fixed part.

    ``model``: the path of a scene MJCF (furniture, a mobile base, a human proxy), or ``None``.
    ``bodies``: poses for named bodies of that model (set on every reset, so a scenario may move
    them without recompiling). ``table``, ``regions`` and ``objects`` are the spec's workspace
    boxes: only the table collides with the arm; regions are thin visual slabs; objects are mocap
    bodies. ``arm``: the robot arm, or ``None`` for a world without one. ``hand_start`` places a
    mocap sphere for the human's hand (``None``: no hand).
    """

    model: str | None = None
    bodies: Mapping[str, BodyPose] = field(default_factory=dict)
    table: Box | None = None
    regions: tuple[Box, ...] = ()
    objects: tuple[Box, ...] = ()
    arm: ArmMount | None = field(default_factory=ArmMount)
    hand_start: tuple[float, float, float] | None = None

    def fixed_part(self) -> WorldLayout:
        """This layout with everything a reset can set (poses, start, hand) at a fixed value:
        two layouts with equal fixed parts share one compiled model."""
        arm = None if self.arm is None else replace(self.arm, base=(0.0, 0.0, 0.0), yaw=0.0, start=None)
        return replace(
            self,
            bodies={},
            objects=tuple(replace(box, center=(0.0, 0.0, 0.0)) for box in self.objects),
            arm=arm,
            hand_start=None if self.hand_start is None else (0.0, 0.0, 0.0),
        )

    def __hash__(self) -> int:  # ``bodies`` is a dict; hash what identifies the layout
        return hash(
            (
                self.model,
                tuple(sorted(self.bodies.items())),
                self.table,
                self.regions,
                self.objects,
                self.arm,
                self.hand_start,
            )
        )


@dataclass(frozen=True, kw_only=True)
class SceneTrace:
    """The state of a world on every recorded tick: enough to pose each of its bodies again.

    Built by :meth:`hritest.sim.World.tracer`, whose ``capture`` records one tick at a time;
    recordings recompile ``layout`` and replay ``qpos`` and the mocap bodies through MuJoCo's
    kinematics, so they draw exactly the model the task ran.
    """

    layout: WorldLayout
    qpos: np.ndarray  # (ticks, nq)
    mocap_pos: np.ndarray  # (ticks, nmocap, 3)
    mocap_quat: np.ndarray  # (ticks, nmocap, 4)
