"""The MuJoCo model of a world: the scene file, the spec's workspace boxes and hand, and the arm
file merged into one :class:`mujoco.MjSpec` and compiled, with the arm located in the result.

Errors name the file and what to change in it or in the spec.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from hritest.errors import HritestError
from hritest.sim.arm import ARM_MJCF
from hritest.sim.layout import START_CONFIG, ArmMount, Box, WorldLayout

HAND_RADIUS = 0.035
_BUILT_IN_ARM = "the built-in arm"  # how messages name hritest.sim.arm.ARM_MJCF
_ARM_PREFIX = "arm/"  # keeps the arm file's names apart from the world's
_HAND = "hand"
_OBJECT_PREFIX = "object/"  # the goal boxes' mocap bodies, apart from the hand and the arm


class WorldModelError(HritestError):
    """A scene or arm MJCF that cannot be loaded or merged, or a layout naming a body it lacks
    (then ``body`` names it, so a caller can point at whatever asked for it)."""

    def __init__(self, message: str, *, body: str | None = None) -> None:
        super().__init__(message)
        self.body = body


class ArmModelError(WorldModelError):
    """An arm MJCF that cannot drive the world: no such site, no hinge joints, no speed limits,
    or a start configuration of the wrong length."""


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
