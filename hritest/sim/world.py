"""The MuJoCo world: a scene model, the spec's table, regions and goal boxes, the arm and the hand.

This is the only module in hritest that imports ``mujoco``: its Python API changes between
versions (4.0 split the package and changed several MJCF semantics), so every call lives here.
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

from hritest.compiled import kernel
from hritest.errors import HritestError
from hritest.sim.arm import ARM_MJCF
from hritest.sim.control import twist_to_joint_velocity
from hritest.sim.layout import START_CONFIG, ArmMount, Box, SceneTrace, WorldLayout

DT = 0.025  # s, the reference's 40 Hz control tick
HAND_RADIUS = 0.035
_BUILT_IN_ARM = "the built-in arm"  # how messages name hritest.sim.arm.ARM_MJCF
_ARM_PREFIX = "arm/"  # keeps the arm file's names apart from the world's
_HAND = "hand"
_OBJECT_PREFIX = "object/"  # the goal boxes' mocap bodies, apart from the hand and the arm
_LIMIT_SLACK = 1e-8  # the reference servo clips to the joint limits +- this
_SHARED_PER_THREAD = 4  # worlds kept by shared_world: one per spec in use is enough
_FIRST_HIDDEN_GROUP = 3  # MuJoCo's convention: geom groups 3 and up hold collision-only geoms
_DEFAULT_RGBA = (0.5, 0.5, 0.5, 1.0)  # a geom with this colour and a material shows the material's
_KINDS = {
    int(mujoco.mjtGeom.mjGEOM_BOX): "box",
    int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
    int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
    int(mujoco.mjtGeom.mjGEOM_CYLINDER): "cylinder",
    int(mujoco.mjtGeom.mjGEOM_ELLIPSOID): "ellipsoid",
    int(mujoco.mjtGeom.mjGEOM_PLANE): "plane",
    int(mujoco.mjtGeom.mjGEOM_MESH): "mesh",
}


class WorldModelError(HritestError):
    """A scene or arm MJCF that cannot be loaded or merged, or a layout naming a body it lacks
    (then ``body`` names it, so a caller can point at whatever asked for it)."""

    def __init__(self, message: str, *, body: str | None = None):
        super().__init__(message)
        self.body = body


class ArmModelError(WorldModelError):
    """An arm MJCF that cannot drive the world: no such site, no hinge joints, no speed limits,
    or a start configuration of the wrong length."""


@dataclass(frozen=True, kw_only=True)
class TwistStep:
    """One tick of :meth:`World.step_twist`: the joint velocities applied, the twist they give
    (``J @ qdot`` at the tick's start) and the reference's "joint limit reached" flag."""

    qdot: np.ndarray
    achieved_twist: np.ndarray
    limit_reached: bool


@dataclass(frozen=True, kw_only=True)
class _Arm:
    """Where the arm sits in the compiled model, its limits, and its mount-free pose."""

    source: str  # the arm file, or _BUILT_IN_ARM, for messages
    joint_names: tuple[str, ...]
    site: int
    qadr: np.ndarray
    dofadr: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    speeds: np.ndarray
    bodies: dict[str, int]  # the arm's named bodies (names as in its file) -> body id
    moving_geoms: np.ndarray  # (ngeom,) bool: geoms on the arm's jointed links
    top: np.ndarray  # the arm's top-level bodies, which the mount places
    top_pos: np.ndarray  # their poses in the arm file's frame
    top_quat: np.ndarray
    default_start: np.ndarray


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

    def __init__(self, *, layout: WorldLayout):
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

    def set_q(self, q) -> None:
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

    def set_hand(self, xyz) -> None:
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

    def step_twist(self, twist, dt: float = DT) -> TwistStep:
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
        # Kinematics give the site pose; comPos gives the com-based dofs mj_jacSite reads.
        # Measured: the pair takes 0.6 us, mj_forward (which adds the dynamics stages) 4.4 us.
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

    def __init__(self, *, world: World):
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


@dataclass(frozen=True, kw_only=True, eq=False)
class Geom:
    """One visible geom of a replayed world, in its body's frame, for a viewer to draw.

    ``kind`` is ``"box"``, ``"sphere"``, ``"capsule"``, ``"cylinder"``, ``"ellipsoid"``,
    ``"plane"`` or ``"mesh"``; ``size`` is MuJoCo's ``geom_size`` for that kind (half sizes,
    radius and half length, ...). ``quat`` is ``(w, x, y, z)``. A mesh has its ``vertices``
    ``(n, 3)`` in the geom's frame and triangle ``faces`` ``(m, 3)``; other kinds have ``None``.
    """

    body: str
    kind: str
    size: tuple[float, float, float]
    pos: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    rgba: tuple[float, float, float, float]
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None


class SceneReplay:
    """The world a :class:`SceneTrace` was recorded in, posed again tick by tick, for recordings.

    It compiles ``trace.layout`` afresh, so a recording draws exactly the model the task ran,
    scene model included. ``geoms`` are the visible ones: MuJoCo's collision-only geoms (groups
    3 and up) and fully transparent ones are left out, and so are height fields and SDFs, which
    have no simple shape to draw. ``bodies`` names the bodies those geoms belong to (the world
    body is ``"world"``), in the order :meth:`poses` returns them.

    Raises:
        WorldModelError: as :class:`World` does, or if the trace's state does not fit the model
            (its files changed since the recording).
    """

    def __init__(self, *, trace: SceneTrace):
        world = World(layout=trace.layout)
        m = world._model
        if trace.qpos.shape[1:] != (m.nq,) or trace.mocap_pos.shape[1:] != (m.nmocap, 3):
            raise WorldModelError(
                f"The scene trace holds {trace.qpos.shape[1:]} joint positions and {trace.mocap_pos.shape[1:]} "
                f"mocap positions per tick; its layout compiles to ({m.nq},) and ({m.nmocap}, 3). Were the "
                "world's MJCF files changed since it was recorded? Run the task again."
            )
        shown = [
            g
            for g in range(m.ngeom)
            if int(m.geom_type[g]) in _KINDS and _colour(m, g)[3] > 0.0 and m.geom_group[g] < _FIRST_HIDDEN_GROUP
        ]
        body_ids = sorted({int(m.geom_bodyid[g]) for g in shown})
        names = {body: m.body(body).name or f"body{body}" for body in body_ids}
        self._model, self._data, self._trace = m, world._data, trace
        self._body_ids = np.array(body_ids, dtype=int)
        self.bodies: tuple[str, ...] = tuple(names[body] for body in body_ids)
        self.geoms: tuple[Geom, ...] = tuple(_geom(m, g, names[int(m.geom_bodyid[g])]) for g in shown)
        self.ticks: int = len(trace.qpos)

    def poses(self, tick: int) -> tuple[np.ndarray, np.ndarray]:
        """World positions ``(len(bodies), 3)`` and quaternions ``(w, x, y, z)``
        ``(len(bodies), 4)`` of :attr:`bodies` at ``tick``."""
        m, d, trace = self._model, self._data, self._trace
        d.qpos[:] = trace.qpos[tick]
        d.mocap_pos[:] = trace.mocap_pos[tick]
        d.mocap_quat[:] = trace.mocap_quat[tick]
        mujoco.mj_kinematics(m, d)
        return d.xpos[self._body_ids].copy(), d.xquat[self._body_ids].copy()


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


def _build(layout: WorldLayout) -> tuple[mujoco.MjModel, _Arm | None, dict[str, int]]:
    """Compiles the layout's fixed part: the scene model, the workspace boxes, the hand and the
    arm, mounted at the origin (:meth:`World._place` moves it)."""
    spec = _scene_spec(layout.model)
    scene_bodies = [body.name for body in spec.bodies if body.name and body.parent is not None]
    _check_names(layout.model, scene_bodies)
    _add_workspace(spec, layout)
    first_arm_body = len(spec.bodies)  # attached last, the arm's bodies compile to the last ids
    arm_file = None if layout.arm is None else _attach_arm(spec, layout.arm)
    try:
        model = spec.compile()
    except ValueError as exc:
        files = [f"the world model {layout.model}"] if layout.model else []
        files += [] if layout.arm is None else [f"the arm {layout.arm.mjcf or _BUILT_IN_ARM}"]
        raise WorldModelError(f"The world ({' and '.join(files) or 'no files'}) does not compile: {exc}") from exc
    arm = None if arm_file is None else _locate_arm(model, layout.arm, first_arm_body, *arm_file)
    return model, arm, {name: _body_id(model, name) for name in scene_bodies}


def _scene_spec(path: str | None) -> mujoco.MjSpec:
    # The scene file is the root, so its compiler settings, options, assets and mesh paths hold.
    if path is None:
        spec = mujoco.MjSpec()
        spec.compiler.degree = False
        return spec
    return _load(path, "world model (world.model in the spec)")


def _attach_arm(spec: mujoco.MjSpec, mount: ArmMount) -> tuple[list[str], np.ndarray | None]:
    """Attaches the arm at the origin; returns what :func:`_locate_arm` needs from its file:
    its site names and its joint speed limits (``None`` if it has none)."""
    arm = (
        mujoco.MjSpec.from_string(ARM_MJCF)
        if mount.mjcf is None
        else _load(mount.mjcf, "arm MJCF (world.arm.model in the spec)")
    )
    sites = [site.name for site in arm.sites if site.name]
    speeds = arm.numeric("velocity_limits")
    spec.attach(arm, frame=spec.worldbody.add_frame(), prefix=_ARM_PREFIX)
    return sites, None if speeds is None else np.array(speeds.data, dtype=float)


def _load(path: str, what: str) -> mujoco.MjSpec:
    try:
        return mujoco.MjSpec.from_file(str(path))
    except ValueError as exc:
        raise WorldModelError(f"Cannot load the {what} {path}: {exc}".rstrip()) from exc


def _check_names(path: str | None, bodies: list[str]) -> None:
    clashes = [name for name in bodies if name == _HAND or name.startswith((_OBJECT_PREFIX, _ARM_PREFIX))]
    if clashes:
        raise WorldModelError(
            f"The world model {path} has bodies named {', '.join(map(repr, clashes))}, which hritest uses for its "
            f"own ('{_HAND}', '{_OBJECT_PREFIX}<name>', '{_ARM_PREFIX}...'); rename them in the file."
        )


def _add_workspace(spec: mujoco.MjSpec, layout: WorldLayout) -> None:
    """The table, region slabs, goal boxes and hand, all in the world body.

    They take their defaults from an empty spec, not the scene file's ``<default>``: a scene
    that hides its geoms in group 3 must not hide the table too.
    """
    plain = mujoco.MjSpec()
    if layout.table is not None:
        _add_box(spec.worldbody, layout.table, plain, pos=layout.table.center, collides=True)
    for box in layout.regions:
        _add_box(spec.worldbody, box, plain, pos=box.center, collides=False)
    for box in layout.objects:
        body = spec.worldbody.add_body(name=_OBJECT_PREFIX + box.name, mocap=True, pos=list(box.center))
        _add_box(body, box, plain, pos=(0.0, 0.0, 0.0), collides=False)
    if layout.hand_start is not None:
        hand = spec.worldbody.add_body(name=_HAND, mocap=True, pos=list(layout.hand_start))
        hand.add_geom(
            default=plain.default,
            type=mujoco.mjtGeom.mjGEOM_SPHERE,
            size=[HAND_RADIUS, 0, 0],
            rgba=[0.9, 0.7, 0.55, 1.0],
            contype=0,
            conaffinity=0,
        )


def _add_box(
    body: mujoco.MjsBody, box: Box, plain: mujoco.MjSpec, *, pos: tuple[float, float, float], collides: bool
) -> None:
    body.add_geom(
        default=plain.default,
        name=box.name,
        type=mujoco.mjtGeom.mjGEOM_BOX,
        pos=list(pos),
        size=list(box.half_size),
        rgba=list(box.rgba),
        contype=int(collides),
        conaffinity=int(collides),
    )


def _locate_arm(
    model: mujoco.MjModel, mount: ArmMount, first_body: int, sites: list[str], speeds: np.ndarray | None
) -> _Arm:
    """The arm's joints, site, limits and top-level bodies in the compiled model."""
    source = mount.mjcf or _BUILT_IN_ARM
    bodies = np.arange(first_body, model.nbody)
    hinges = [
        j
        for j in range(model.njnt)
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE and model.jnt_bodyid[j] >= first_body
    ]
    if not hinges:
        raise ArmModelError(f"The arm MJCF {source} has no hinge joints to drive.")
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, _ARM_PREFIX + mount.ee_site)
    if site < 0:
        raise ArmModelError(
            f"The arm MJCF {source} has no site named {mount.ee_site!r} (its sites: "
            f"{', '.join(map(repr, sites)) or 'none'}); set "
            "world.arm.ee_site in the spec to the name of its tool site."
        )
    if speeds is None or len(speeds) != len(hinges):
        raise ArmModelError(
            f'The arm MJCF {source} needs <custom><numeric name="velocity_limits" data="..."/></custom> with '
            f"one speed (rad/s) per hinge joint ({len(hinges)})."
        )
    limited = model.jnt_limited[hinges].astype(bool)
    qadr = model.jnt_qposadr[hinges].copy()
    moving = np.zeros(model.nbody, dtype=bool)
    moving[bodies] = model.body_weldid[bodies] != 0
    top = bodies[model.body_parentid[bodies] == 0]
    return _Arm(
        source=source,
        joint_names=tuple(model.joint(j).name.removeprefix(_ARM_PREFIX) for j in hinges),
        site=site,
        qadr=qadr,
        dofadr=model.jnt_dofadr[hinges].copy(),
        lower=np.where(limited, model.jnt_range[hinges, 0], -np.inf),
        upper=np.where(limited, model.jnt_range[hinges, 1], np.inf),
        speeds=speeds,
        bodies={model.body(b).name.removeprefix(_ARM_PREFIX): int(b) for b in bodies if model.body(b).name},
        moving_geoms=moving[model.geom_bodyid],
        top=top,
        top_pos=model.body_pos[top].copy(),
        top_quat=model.body_quat[top].copy(),
        default_start=np.array(START_CONFIG if mount.mjcf is None else model.qpos0[qadr], dtype=float),
    )


def _start(arm: _Arm, mount: ArmMount) -> np.ndarray:
    if mount.start is None:
        return arm.default_start
    start = np.array(mount.start, dtype=float)
    if start.shape != arm.default_start.shape:
        raise ArmModelError(
            f"world.arm.start has {start.size} angles, but the arm {arm.source} has {len(arm.qadr)} hinge joints "
            f"({', '.join(arm.joint_names)}); give one angle (rad) per joint, in file order."
        )
    return start


def _body_id(model: mujoco.MjModel, name: str) -> int:
    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)


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


def _colour(model: mujoco.MjModel, geom: int) -> np.ndarray:
    # MJCF's rule: a geom's own rgba wins over its material's unless it is the default colour.
    rgba, material = model.geom_rgba[geom], model.geom_matid[geom]
    return model.mat_rgba[material] if material >= 0 and tuple(rgba) == _DEFAULT_RGBA else rgba


def _geom(model: mujoco.MjModel, geom: int, body: str) -> Geom:
    kind = _KINDS[int(model.geom_type[geom])]
    vertices = faces = None
    if kind == "mesh":
        mesh = model.geom_dataid[geom]
        first_vertex, first_face = model.mesh_vertadr[mesh], model.mesh_faceadr[mesh]
        vertices = model.mesh_vert[first_vertex : first_vertex + model.mesh_vertnum[mesh]].copy()
        faces = model.mesh_face[first_face : first_face + model.mesh_facenum[mesh]].copy()
    return Geom(
        body=body,
        kind=kind,
        size=tuple(float(v) for v in model.geom_size[geom]),
        pos=tuple(float(v) for v in model.geom_pos[geom]),
        quat=tuple(float(v) for v in model.geom_quat[geom]),
        rgba=tuple(float(v) for v in _colour(model, geom)),
        vertices=vertices,
        faces=faces,
    )
