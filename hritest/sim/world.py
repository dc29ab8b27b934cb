"""The MuJoCo world: a scene model, the spec's table, regions and goal boxes, the arm and the hand.

Only :mod:`hritest.sim` imports ``mujoco``: its Python API changes between versions (4.0 split
the package and changed several MJCF semantics), so every call lives in this module,
:mod:`hritest.sim.mjcf` (loading and merging the model files) and :mod:`hritest.sim.scene_replay`.
The arm moves kinematically, as the reference's simulated servo did: each tick sets
``q <- clip(q + qdot * dt)`` and recomputes the forward kinematics; no dynamics are stepped.

Building a world (parse the files, compile, allocate MuJoCo's data arena) takes milliseconds,
more than a short episode's whole tick loop, while the scenarios of one spec differ only in where
things stand. So everything a scenario may move is set on every reset instead of compiled in: the
goal boxes and the hand are mocap bodies, and the scene model's bodies and the arm's mount are
placed by writing their poses into the compiled model. :func:`shared_world` then hands a task
the world its thread already built for the same fixed part (:meth:`WorldLayout.fixed_part`).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from hritest.errors import HritestError
from hritest.jit import kernel
from hritest.sim.control import twist_to_joint_velocity
from hritest.sim.layout import SceneTrace, WorldLayout
from hritest.sim.mjcf import _HAND, _OBJECT_PREFIX, WorldModelError, _Arm, _body_id, _build, _start

DT = 0.025  # s, the reference's 40 Hz control tick
_LIMIT_SLACK = 1e-8  # the reference servo clips to the joint limits +- this
_SHARED_PER_THREAD = 4  # worlds kept by shared_world: one per spec in use is enough


@dataclass(frozen=True, kw_only=True)
class TwistStep:
    """One tick of :meth:`World.step_twist`: the joint velocities applied, the twist they give
    (``J @ qdot`` at the tick's start) and the reference's "joint limit reached" flag."""

    qdot: np.ndarray
    achieved_twist: np.ndarray
    limit_reached: bool


@dataclass(frozen=True, kw_only=True)
class _Placement:
    """What a reset writes into the model, resolved from a layout before anything changes."""

    body_pos: np.ndarray
    body_quat: np.ndarray
    qpos0: np.ndarray
    start: np.ndarray | None  # None: no arm


class World:
    """One compiled MuJoCo model and its data: a scene, the arm moved kinematically, the hand.

    Args:
        layout: the world to build (see :class:`WorldLayout`).

    Raises:
        WorldModelError: if the scene or arm file cannot be read or merged, or ``layout.bodies``
            names a body the scene model does not have.
        ArmModelError: if the arm file has no hinge joints, no site named ``ee_site``, no
            ``velocity_limits`` numeric of one value per joint, or the start configuration has
            the wrong length.
    """

    def __init__(self, *, layout: WorldLayout) -> None:
        model, arm, scene_bodies = _build(layout)
        self._model, self._arm, self._scene_bodies = model, arm, scene_bodies
        self._data = mujoco.MjData(model)
        # The compiled poses: every reset starts from these, so a body a previous layout moved
        # goes back to where its file puts it.
        self._compiled = (model.body_pos.copy(), model.body_quat.copy(), model.qpos0.copy())
        self._hand = model.body_mocapid[_body_id(model, _HAND)] if layout.hand_start is not None else None
        self._objects = np.array(
            [model.body_mocapid[_body_id(model, _OBJECT_PREFIX + box.name)] for box in layout.objects], dtype=int
        )
        if arm is not None:
            self._q = np.empty(len(arm.qadr))
            self._floor, self._ceiling = arm.lower - _LIMIT_SLACK, arm.upper + _LIMIT_SLACK
            self._jac_full = np.zeros((6, model.nv))
            self._jac = np.zeros((6, len(arm.qadr)))
            self._ee_pose = np.eye(4)
            # Views into MjData (its buffers never move): cheaper than looking the rows up every tick.
            self._site_rotation = self._data.site_xmat[arm.site].reshape(3, 3)
            self._site_position = self._data.site_xpos[arm.site]
            self._qpos = self._data.qpos
        self._placement = self._place(layout)
        self.layout = layout
        self.reset()

    def reset(self) -> None:
        """Fresh data (nothing leaks between episodes); scene bodies, arm mount, goal boxes and
        hand where the layout puts them; the arm at its start configuration."""
        m, d, placement = self._model, self._data, self._placement
        m.body_pos[:] = placement.body_pos
        m.body_quat[:] = placement.body_quat
        m.qpos0[:] = placement.qpos0
        mujoco.mj_resetData(m, d)  # also puts mocap bodies at their (just written) body poses
        if self._hand is not None:
            d.mocap_pos[self._hand] = self.layout.hand_start
        if len(self._objects):
            d.mocap_pos[self._objects] = [box.center for box in self.layout.objects]
        if placement.start is None:
            mujoco.mj_kinematics(m, d)
        else:
            self.set_q(placement.start)

    def show(self, layout: WorldLayout) -> None:
        """Switches to ``layout`` and resets; it may differ from this world's only in what a
        reset sets (goal box centres, body poses, the arm's base, yaw and start, the hand's start).

        Raises:
            ValueError: if anything else differs (that needs a new :class:`World`).
            WorldModelError: as :class:`World` does, for ``layout``'s poses; nothing changes then.
        """
        if layout.fixed_part() != self.layout.fixed_part():
            raise ValueError(
                "World.show can only change what a reset sets (goal box centres, body poses, the arm's "
                "base, yaw and start, the hand's start); build a new World for this layout"
            )
        self._placement = self._place(layout)
        self.layout = layout
        self.reset()

    def tracer(self) -> SceneTracer:
        """A recorder of this world's state, for a :class:`SceneTrace`: call its ``capture`` once
        per tick and its ``finish`` at the end of the episode."""
        return SceneTracer(world=self)

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The arm's hinge joints, named as in its file, in file order."""
        return self._need_arm().joint_names

    @property
    def q(self) -> np.ndarray:
        """The arm's joint angles (a copy)."""
        self._need_arm()
        return self._q.copy()

    def set_q(self, q: ArrayLike) -> None:
        """Teleports the arm (no limit check: the reference teleported too) and updates poses."""
        arm = self._need_arm()
        self._q[:] = q
        self._data.qpos[arm.qadr] = self._q
        self._forward(arm)

    @property
    def joint_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lower, upper)`` joint limits, ``-inf``/``+inf`` for joints that turn without end."""
        arm = self._need_arm()
        return arm.lower.copy(), arm.upper.copy()

    @property
    def velocity_limits(self) -> np.ndarray:
        """Joint speed limits (rad/s)."""
        return self._need_arm().speeds.copy()

    def ee_pose(self) -> np.ndarray:
        """The tool site's 4x4 pose in the world frame (a copy)."""
        self._need_arm()
        return self._ee_pose.copy()

    def jacobian(self) -> np.ndarray:
        """(6, n_joints) world-frame Jacobian of the tool site: linear rows, then angular."""
        self._need_arm()
        return self._jac.copy()

    def set_hand(self, xyz: ArrayLike) -> None:
        """Moves the hand sphere (a mocap body: it has no dynamics and collides with nothing)."""
        self._data.mocap_pos[self._hand_id()] = xyz

    def hand_position(self) -> np.ndarray:
        """The hand sphere's centre."""
        return self._data.mocap_pos[self._hand_id()].copy()

    def self_collision(self) -> bool:
        """Whether any moving arm link penetrates another link, the pedestal, the table or a
        colliding geom of the scene model.

        Regions, goal boxes and the hand have contype 0, and MuJoCo already skips parent-child
        pairs and the files' ``<exclude>`` pairs. A contact counts when it involves a moving arm
        link and has negative distance (touching is not a collision).
        """
        arm = self._need_arm()
        mujoco.mj_collision(self._model, self._data)
        n = self._data.ncon
        if n == 0:
            return False
        contacts = self._data.contact
        involved = arm.moving_geoms[contacts.geom[:n]].any(axis=1)
        return bool(np.any(involved & (contacts.dist[:n] < 0.0)))

    def link_poses(self) -> dict[str, np.ndarray]:
        """Name (as in the arm MJCF) -> 4x4 world pose of every named arm body."""
        poses = {}
        for name, body in self._need_arm().bodies.items():
            pose = np.eye(4)
            pose[:3, :3] = self._data.xmat[body].reshape(3, 3)
            pose[:3, 3] = self._data.xpos[body]
            poses[name] = pose
        return poses

    def step_twist(self, twist: ArrayLike, dt: float = DT) -> TwistStep:
        """One tick: resolve ``twist`` into joint velocities, integrate them, update poses.

        The velocities come from :func:`hritest.sim.control.twist_to_joint_velocity` with this
        arm's limits; the integration is the reference servo's
        ``q <- clip(q + qdot * dt, lower - 1e-8, upper + 1e-8)``.
        """
        arm = self._need_arm()
        twist = np.asarray(twist, dtype=float)
        qdot, limit_reached = twist_to_joint_velocity(
            self._jac,
            twist,
            self._q,
            lower=arm.lower,
            upper=arm.upper,
            velocity_limits=arm.speeds,
            dt=dt,
        )
        achieved = _integrate(self._jac, qdot, self._q, dt, self._floor, self._ceiling, self._qpos, arm.qadr)
        self._forward(arm)
        return TwistStep(qdot=qdot, achieved_twist=achieved, limit_reached=limit_reached)

    def _forward(self, arm: _Arm) -> None:
        # Kinematics give the site pose; comPos gives the com-based dofs mj_jacSite reads. The pair
        # skips the dynamics stages that mj_forward would add (docs/decisions.md, "A kinematic arm").
        m, d = self._model, self._data
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_jacSite(m, d, self._jac_full[:3], self._jac_full[3:], arm.site)
        # The EE pose is kept up to date here, so that reading it (every tick) is one copy.
        _gather(self._jac_full, arm.dofadr, self._jac, self._site_rotation, self._site_position, self._ee_pose)

    def _need_arm(self) -> _Arm:
        if self._arm is None:
            raise HritestError("This world has no arm: set world.arm in the spec.")
        return self._arm

    def _hand_id(self) -> int:
        if self._hand is None:
            raise HritestError("This world has no hand: its layout's hand_start is None.")
        return self._hand

    def _place(self, layout: WorldLayout) -> _Placement:
        """The compiled poses with ``layout``'s body poses and arm mount applied."""
        body_pos, body_quat, qpos0 = (values.copy() for values in self._compiled)
        for name, pose in layout.bodies.items():
            body = self._scene_body(layout, name)
            file_pos = body_pos[body]
            body_pos[body] = [file_pos[i] if v is None else v for i, v in enumerate((pose.x, pose.y, pose.z))]
            body_quat[body] = _turned(body_quat[body], pose.yaw)
            _move_free_joint(self._model, body, body_pos[body], body_quat[body], qpos0)
        if self._arm is None:
            return _Placement(body_pos=body_pos, body_quat=body_quat, qpos0=qpos0, start=None)
        mount, arm = layout.arm, self._arm
        body_pos[arm.top] = np.asarray(mount.base, dtype=float) + arm.top_pos @ _yaw_matrix(mount.yaw).T
        for body, quat in zip(arm.top, arm.top_quat):
            body_quat[body] = _turned(quat, mount.yaw)
        return _Placement(body_pos=body_pos, body_quat=body_quat, qpos0=qpos0, start=_start(arm, mount))

    def _scene_body(self, layout: WorldLayout, name: str) -> int:
        body = self._scene_bodies.get(name)
        if body is None:
            where = (
                f"The world model {layout.model} has no body named {name!r}; its named bodies: "
                f"{', '.join(self._scene_bodies) or 'none'}."
                if layout.model
                else f"a parameter moves a body named {name!r}, but the world has no model file (world.model)."
            )
            raise WorldModelError(f"{where} Fix the parameter that binds {name}.x|y|z|yaw in the spec.", body=name)
        return body


class SceneTracer:
    """Copies a world's joint and mocap state once per tick, for :class:`SceneTrace`.

    ``capture`` runs inside every search evaluation, so it only copies three small arrays; the
    recording recomputes the poses from them when (rarely) one is made.
    """

    def __init__(self, *, world: World) -> None:
        self._world = world
        self._qpos: list[np.ndarray] = []
        self._mocap_pos: list[np.ndarray] = []
        self._mocap_quat: list[np.ndarray] = []

    def capture(self) -> None:
        """Records the world's state now (call once per tick)."""
        data = self._world._data
        self._qpos.append(data.qpos.copy())
        self._mocap_pos.append(data.mocap_pos.copy())
        self._mocap_quat.append(data.mocap_quat.copy())

    def finish(self) -> SceneTrace:
        """The captured ticks, with the world's current layout."""
        m, ticks = self._world._model, len(self._qpos)
        return SceneTrace(
            layout=self._world.layout,
            qpos=np.array(self._qpos, dtype=float).reshape(ticks, m.nq),
            mocap_pos=np.array(self._mocap_pos, dtype=float).reshape(ticks, m.nmocap, 3),
            mocap_quat=np.array(self._mocap_quat, dtype=float).reshape(ticks, m.nmocap, 4),
        )


@kernel
def _integrate(
    jac: np.ndarray,
    qdot: np.ndarray,
    q: np.ndarray,
    dt: float,
    floor: np.ndarray,
    ceiling: np.ndarray,
    qpos: np.ndarray,
    qadr: np.ndarray,
) -> np.ndarray:
    """``J qdot`` (the twist achieved), then ``q <- clip(q + qdot dt, floor, ceiling)``, in ``qpos`` too."""
    achieved = jac @ qdot
    for i in range(len(q)):
        q[i] = min(max(q[i] + qdot[i] * dt, floor[i]), ceiling[i])
        qpos[qadr[i]] = q[i]
    return achieved


@kernel
def _gather(
    jac_full: np.ndarray,
    dofadr: np.ndarray,
    jac: np.ndarray,
    site_rotation: np.ndarray,
    site_position: np.ndarray,
    ee_pose: np.ndarray,
) -> None:
    """The arm's Jacobian columns out of MuJoCo's full one, and the EE site's pose as 4x4."""
    for i in range(len(dofadr)):
        jac[:, i] = jac_full[:, dofadr[i]]
    ee_pose[:3, :3] = site_rotation
    ee_pose[:3, 3] = site_position


def shared_world(layout: WorldLayout) -> World:
    """A reset world showing ``layout``, reused by later calls on this thread.

    Built once per layout's fixed part (:meth:`WorldLayout.fixed_part`: everything but goal box
    centres, body poses, the arm's base, yaw and start, and the hand's start), then switched with
    :meth:`World.show`. Each thread keeps its own few, so parallel evaluations in threads never
    share one; but within a thread the world is the same object every time, so finish with it
    (one episode) before asking again.
    """
    worlds = getattr(_local, "worlds", None)
    if worlds is None:
        worlds = _local.worlds = OrderedDict()
    key = layout.fixed_part()
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


def _yaw_matrix(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _turned(quat: np.ndarray, yaw: float) -> np.ndarray:
    """``quat`` turned by ``yaw`` about the z axis of the frame it is given in (exact for yaw 0)."""
    out = np.empty(4)
    mujoco.mju_mulQuat(out, np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]), np.asarray(quat, dtype=float))
    return out


def _move_free_joint(model: mujoco.MjModel, body: int, pos: np.ndarray, quat: np.ndarray, qpos0: np.ndarray) -> None:
    """A free-floating body's pose is its joint's, not its ``body_pos``: set its reset value too."""
    if model.body_jntnum[body] and model.jnt_type[model.body_jntadr[body]] == mujoco.mjtJoint.mjJNT_FREE:
        adr = model.jnt_qposadr[model.body_jntadr[body]]
        qpos0[adr : adr + 3] = pos
        qpos0[adr + 3 : adr + 7] = quat
