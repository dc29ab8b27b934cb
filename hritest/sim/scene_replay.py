"""The world a :class:`~hritest.sim.layout.SceneTrace` was recorded in, posed again tick by tick:
what a recording draws."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from hritest.sim.layout import SceneTrace
from hritest.sim.mjcf import WorldModelError
from hritest.sim.world import World

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

    def __init__(self, *, trace: SceneTrace) -> None:
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
