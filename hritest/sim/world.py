"""The MuJoCo world: table, workspace regions, goal boxes, the arm and the human's hand.

This is the only module in hritest that imports ``mujoco``: its Python API changes between
versions (4.0 split the package and changed several MJCF semantics), so every call lives here.
The arm moves kinematically, as the reference's simulated servo did: each tick sets
``q <- clip(q + qdot * dt)`` and recomputes the forward kinematics; no dynamics are stepped.

Building a world (parse the arm, compile, allocate MuJoCo's data arena) takes milliseconds, more
than a short episode's whole tick loop, while the scenarios of one spec differ only in where
the goal boxes are. So the boxes are mocap bodies, placed from the layout on every reset, and
:func:`shared_world` hands a task the world its thread already built for the same fixed parts.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass, replace

import mujoco
import numpy as np

from hritest.compiled import kernel
from hritest.errors import HritestError
from hritest.sim.arm import ARM_MJCF
from hritest.sim.control import twist_to_joint_velocity

DT = 0.025  # s, the reference's 40 Hz control tick
ROBOT_BASE = (0.409, 0.338, 0.795)
START_CONFIG = (-2.38, -0.43, -0.28, -0.75, 0.0, 3.55)
HAND_RADIUS = 0.035
_ARM_PREFIX = "arm/"  # keeps the arm file's names apart from the world's
_LIMIT_SLACK = 1e-8  # the reference servo clips to the joint limits +- this
_OBJECT_PREFIX = "object/"  # the goal boxes' mocap bodies, apart from the hand and the arm
_SHARED_PER_THREAD = 4  # worlds kept by shared_world: one per spec in use is enough


class ArmModelError(HritestError):
    """An arm MJCF that cannot drive the world: no such site, no hinge joints, no speed limits."""


@dataclass(frozen=True, kw_only=True)
class Box:
    """An axis-aligned box: a table, a workspace region or a goal object."""

    name: str
    center: tuple[float, float, float]
    half_size: tuple[float, float, float]
    rgba: tuple[float, float, float, float] = (0.6, 0.6, 0.6, 1.0)

    def __post_init__(self):
        for field, size in (("center", 3), ("half_size", 3), ("rgba", 4)):
            value = tuple(float(v) for v in getattr(self, field))
            if len(value) != size:
                raise ValueError(f"Box {self.name!r}: {field} needs {size} numbers, got {value}")
            object.__setattr__(self, field, value)


@dataclass(frozen=True, kw_only=True)
class WorldLayout:
    """What a world contains; a :class:`World` compiles it once.

    Only the table (and the arm's own pedestal) can collide with the arm. ``regions`` are thin
    visual slabs and ``objects`` the goal boxes (mocap bodies, see :meth:`World.show`), which
    never collide with or block the arm.
    ``hand_start`` places a mocap sphere for the human's hand (``None``: no hand).
    ``arm_mjcf`` is the path of a user's arm MJCF (``None``: the built-in Mico-like arm, see
    :mod:`hritest.sim.arm`); its hinge joints, in file order, are the arm's joints, ``ee_site``
    names its tool site, and ``<numeric name="velocity_limits">`` gives the joint speed limits.
    """

    table: Box
    regions: tuple[Box, ...] = ()
    objects: tuple[Box, ...] = ()
    robot_base: tuple[float, float, float] = ROBOT_BASE
    start_config: tuple[float, ...] = START_CONFIG
    hand_start: tuple[float, float, float] | None = None
    arm_mjcf: str | None = None
    ee_site: str = "ee"


@dataclass(frozen=True, kw_only=True)
class TwistStep:
    """One tick of :meth:`World.step_twist`: the joint velocities applied, the twist they give
    (``J @ qdot`` at the tick's start) and the reference's "joint limit reached" flag."""

    qdot: np.ndarray
    achieved_twist: np.ndarray
    limit_reached: bool


class World:
    """One compiled MuJoCo model and its data: the arm, moved kinematically, and its scene.

    Args:
        layout: the scene to build.

    Raises:
        ArmModelError: if the arm MJCF has no hinge joints, no site named ``layout.ee_site``, no
            ``velocity_limits`` numeric of one value per joint, or a start configuration of the
            wrong length.
    """

    def __init__(self, *, layout: WorldLayout):
        self.layout = layout
        arm = (
            mujoco.MjSpec.from_file(layout.arm_mjcf)
            if layout.arm_mjcf
            else mujoco.MjSpec.from_string(ARM_MJCF)
        )
        arm_bodies = [body.name for body in arm.bodies if body.name and body.parent is not None]
        speeds = arm.numeric("velocity_limits")
        self._model = _compile(layout, arm)
        self._data = mujoco.MjData(self._model)
        m = self._model
        hinges, site = _arm_joints_and_site(m, layout)
        if speeds is None or len(speeds.data) != len(hinges):
            raise ArmModelError(
                f'The arm MJCF needs <custom><numeric name="velocity_limits" data="..."/>'
                f"</custom> with one speed (rad/s) per hinge joint ({len(hinges)})."
            )
        self.joint_names = tuple(m.joint(j).name.removeprefix(_ARM_PREFIX) for j in hinges)
        self._site = site
        self._qadr = m.jnt_qposadr[hinges].copy()
        self._dofadr = m.jnt_dofadr[hinges].copy()
        limited = m.jnt_limited[hinges].astype(bool)
        self._lower = np.where(limited, m.jnt_range[hinges, 0], -np.inf)
        self._upper = np.where(limited, m.jnt_range[hinges, 1], np.inf)
        self._floor, self._ceiling = self._lower - _LIMIT_SLACK, self._upper + _LIMIT_SLACK
        self._speeds = np.array(speeds.data, dtype=float)
        self._bodies = {
            name: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, _ARM_PREFIX + name)
            for name in arm_bodies
        }
        moving = m.body_weldid != 0
        arm_body = np.zeros(m.nbody, dtype=bool)
        arm_body[list(self._bodies.values())] = True
        self._arm_geom = (arm_body & moving)[m.geom_bodyid]
        self._hand = (
            m.body_mocapid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "hand")]
            if layout.hand_start is not None
            else None
        )
        self._objects = np.array([
            m.body_mocapid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, _OBJECT_PREFIX + box.name)]
            for box in layout.objects
        ], dtype=int)
        self._start = np.array(layout.start_config, dtype=float)
        self._q = np.empty(len(hinges))
        self._jac_full = np.zeros((6, m.nv))
        self._jac = np.zeros((6, len(hinges)))
        self._ee_pose = np.eye(4)
        # Views into MjData (its buffers never move): cheaper than looking the rows up every tick.
        self._site_rotation = self._data.site_xmat[site].reshape(3, 3)
        self._site_position = self._data.site_xpos[site]
        self._qpos = self._data.qpos
        self.reset()

    def reset(self) -> None:
        """Fresh data (nothing leaks between episodes), arm at the start, hand at its start,
        goal boxes where the layout puts them."""
        mujoco.mj_resetData(self._model, self._data)
        if self._hand is not None:
            self._data.mocap_pos[self._hand] = self.layout.hand_start
        if len(self._objects):
            self._data.mocap_pos[self._objects] = [box.center for box in self.layout.objects]
        self.set_q(self._start)

    def show(self, layout: WorldLayout) -> None:
        """Switches to ``layout``, which may differ from this world's only in where the goal
        boxes are, and resets.

        Raises:
            ValueError: if anything else differs (that needs a new :class:`World`).
        """
        if _fixed_part(layout) != _fixed_part(self.layout):
            raise ValueError("World.show can only move the goal boxes; build a new World for this layout")
        self.layout = layout
        self.reset()

    @property
    def q(self) -> np.ndarray:
        """The arm's joint angles (a copy)."""
        return self._q.copy()

    def set_q(self, q) -> None:
        """Teleports the arm (no limit check: the reference teleported too) and updates poses."""
        self._q[:] = q
        self._data.qpos[self._qadr] = self._q
        self._forward()

    @property
    def joint_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lower, upper)`` joint limits, ``-inf``/``+inf`` for joints that turn without end."""
        return self._lower.copy(), self._upper.copy()

    @property
    def velocity_limits(self) -> np.ndarray:
        """Joint speed limits (rad/s)."""
        return self._speeds.copy()

    def ee_pose(self) -> np.ndarray:
        """The tool site's 4x4 pose in the world frame (a copy)."""
        return self._ee_pose.copy()

    def jacobian(self) -> np.ndarray:
        """(6, n_joints) world-frame Jacobian of the tool site: linear rows, then angular."""
        return self._jac.copy()

    def set_hand(self, xyz) -> None:
        """Moves the hand sphere (a mocap body: it has no dynamics and collides with nothing)."""
        self._data.mocap_pos[self._hand_id()] = xyz

    def hand_position(self) -> np.ndarray:
        """The hand sphere's centre."""
        return self._data.mocap_pos[self._hand_id()].copy()

    def self_collision(self) -> bool:
        """Whether any arm link penetrates another link, the table or the pedestal.

        Only the table and the arm's geoms can collide at all (regions, goal boxes and the hand
        have contype 0), and MuJoCo already skips parent-child pairs and the arm file's
        ``<exclude>`` pairs. A contact counts when it involves an arm link and has negative
        distance (touching is not a collision).
        """
        mujoco.mj_collision(self._model, self._data)
        n = self._data.ncon
        if n == 0:
            return False
        contacts = self._data.contact
        involved = self._arm_geom[contacts.geom[:n]].any(axis=1)
        return bool(np.any(involved & (contacts.dist[:n] < 0.0)))

    def link_poses(self) -> dict[str, np.ndarray]:
        """Name (as in the arm MJCF) -> 4x4 world pose of every named arm body, for recordings."""
        poses = {}
        for name, body in self._bodies.items():
            pose = np.eye(4)
            pose[:3, :3] = self._data.xmat[body].reshape(3, 3)
            pose[:3, 3] = self._data.xpos[body]
            poses[name] = pose
        return poses

    def step_twist(self, twist, dt: float = DT) -> TwistStep:
        """One tick: resolve ``twist`` into joint velocities, integrate them, update poses.

        The velocities come from :func:`hritest.sim.control.twist_to_joint_velocity` with this
        arm's limits; the integration is the reference servo's
        ``q <- clip(q + qdot * dt, lower - 1e-8, upper + 1e-8)``.
        """
        twist = np.asarray(twist, dtype=float)
        qdot, limit_reached = twist_to_joint_velocity(
            self._jac,
            twist,
            self._q,
            lower=self._lower,
            upper=self._upper,
            velocity_limits=self._speeds,
            dt=dt,
        )
        achieved = _integrate(self._jac, qdot, self._q, dt, self._floor, self._ceiling, self._qpos, self._qadr)
        self._forward()
        return TwistStep(qdot=qdot, achieved_twist=achieved, limit_reached=limit_reached)

    def _forward(self) -> None:
        # Kinematics give the site pose; comPos gives the com-based dofs mj_jacSite reads.
        # Measured: the pair takes 0.6 us, mj_forward (which adds the dynamics stages) 4.4 us.
        m, d = self._model, self._data
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_jacSite(m, d, self._jac_full[:3], self._jac_full[3:], self._site)
        # The EE pose is kept up to date here, so that reading it (every tick) is one copy.
        _gather(self._jac_full, self._dofadr, self._jac, self._site_rotation, self._site_position, self._ee_pose)

    def _hand_id(self) -> int:
        if self._hand is None:
            raise HritestError("This world has no hand: its layout's hand_start is None.")
        return self._hand


@kernel
def _integrate(jac: np.ndarray, qdot: np.ndarray, q: np.ndarray, dt: float, floor: np.ndarray, ceiling: np.ndarray,
               qpos: np.ndarray, qadr: np.ndarray) -> np.ndarray:
    """``J qdot`` (the twist achieved), then ``q <- clip(q + qdot dt, floor, ceiling)``, in ``qpos`` too."""
    achieved = jac @ qdot
    for i in range(len(q)):
        q[i] = min(max(q[i] + qdot[i] * dt, floor[i]), ceiling[i])
        qpos[qadr[i]] = q[i]
    return achieved


@kernel
def _gather(jac_full: np.ndarray, dofadr: np.ndarray, jac: np.ndarray, site_rotation: np.ndarray,
            site_position: np.ndarray, ee_pose: np.ndarray) -> None:
    """The arm's Jacobian columns out of MuJoCo's full one, and the EE site's pose as 4x4."""
    for i in range(len(dofadr)):
        jac[:, i] = jac_full[:, dofadr[i]]
    ee_pose[:3, :3] = site_rotation
    ee_pose[:3, 3] = site_position


def shared_world(layout: WorldLayout) -> World:
    """A reset world showing ``layout``, reused by later calls on this thread.

    Built once per layout's fixed part (everything but the goal boxes' positions), then moved
    with :meth:`World.show`. Each thread keeps its own few, so parallel evaluations in threads
    never share one; but within a thread the world is the same object every time, so finish
    with it (one episode) before asking again.
    """
    worlds = getattr(_local, "worlds", None)
    if worlds is None:
        worlds = _local.worlds = OrderedDict()
    key = _fixed_part(layout)
    world = worlds.get(key)
    if world is None:
        world = worlds[key] = World(layout=layout)
        if len(worlds) > _SHARED_PER_THREAD:
            worlds.popitem(last=False)
    else:
        worlds.move_to_end(key)
        world.show(layout)
    return world


_local = threading.local()


def _fixed_part(layout: WorldLayout) -> WorldLayout:
    return replace(layout, objects=tuple(replace(box, center=(0.0, 0.0, 0.0)) for box in layout.objects))


def _arm_joints_and_site(m: mujoco.MjModel, layout: WorldLayout) -> tuple[list[int], int]:
    # The world itself adds no joints, so every hinge is the arm's, in the arm file's order.
    hinges = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    if not hinges:
        raise ArmModelError("The arm MJCF has no hinge joints to drive.")
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, _ARM_PREFIX + layout.ee_site)
    if site < 0:
        raise ArmModelError(
            f"The arm MJCF has no site named {layout.ee_site!r}; set WorldLayout.ee_site "
            "to the name of its tool site."
        )
    if len(layout.start_config) != len(hinges):
        raise ArmModelError(
            f"start_config has {len(layout.start_config)} angles; the arm has "
            f"{len(hinges)} hinge joints."
        )
    return hinges, site


def _compile(layout: WorldLayout, arm: mujoco.MjSpec) -> mujoco.MjModel:
    spec = mujoco.MjSpec()
    spec.compiler.degree = False
    _add_box(spec.worldbody, layout.table, pos=layout.table.center, collides=True)
    for box in layout.regions:
        _add_box(spec.worldbody, box, pos=box.center, collides=False)
    for box in layout.objects:
        body = spec.worldbody.add_body(name=_OBJECT_PREFIX + box.name, mocap=True, pos=list(box.center))
        _add_box(body, box, pos=(0.0, 0.0, 0.0), collides=False)
    if layout.hand_start is not None:
        hand = spec.worldbody.add_body(name="hand", mocap=True, pos=list(layout.hand_start))
        hand.add_geom(
            type=mujoco.mjtGeom.mjGEOM_SPHERE,
            size=[HAND_RADIUS, 0, 0],
            rgba=[0.9, 0.7, 0.55, 1.0],
            contype=0,
            conaffinity=0,
        )
    mount = spec.worldbody.add_frame(pos=list(layout.robot_base))
    spec.attach(arm, frame=mount, prefix=_ARM_PREFIX)
    return spec.compile()


def _add_box(body: mujoco.MjsBody, box: Box, *, pos: tuple[float, float, float], collides: bool) -> None:
    body.add_geom(
        name=box.name,
        type=mujoco.mjtGeom.mjGEOM_BOX,
        pos=list(pos),
        size=list(box.half_size),
        rgba=list(box.rgba),
        contype=int(collides),
        conaffinity=int(collides),
    )
