"""The traced MuJoCo world of a rollout, posed tick by tick and logged: each body's pose and geoms."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hritest.errors import HritestError
from hritest.recording.entities import TIMELINE, entity_path, under, world_frame

_STILL = 1e-9  # a body whose pose never changes more than this (m, quaternion units) is static
_PLANE_HALF = 5.0  # m: MuJoCo draws a plane of size 0 without end; a recording needs an edge
_PLANE_THICKNESS = 0.002  # m: a plane is drawn as a thin box whose top face is the plane
_CAMERA = np.array([0.8, -0.7, 0.55])  # eye offset per metre of the scene's diagonal: a +x, -y, +z corner


@dataclass(frozen=True)
class ReplayedScene:
    """The traced world replayed once, so that the blueprint's camera and the log share the poses."""

    bodies: tuple[str, ...]
    geoms: tuple[Any, ...]  # hritest.sim.Geom
    time: np.ndarray  # (ticks,) seconds
    positions: np.ndarray  # (ticks, bodies, 3) world frame
    quaternions: np.ndarray  # (ticks, bodies, 4) wxyz, world frame


def replay_scene(rollout: Any) -> tuple[ReplayedScene | None, str]:
    """Poses every body of ``rollout.scene`` on every tick; ``(None, why)`` if the traced world
    cannot be compiled here (an MJCF file moved since the run), so the rest still records."""
    if rollout is None or rollout.scene is None:
        return None, ""
    from hritest.sim import SceneReplay

    try:
        replay = SceneReplay(trace=rollout.scene)
    except (HritestError, ValueError) as exc:
        return None, str(exc)
    ticks = min(replay.ticks, len(rollout.time))
    if not ticks:
        return None, "the scene trace holds no tick"
    poses = [replay.poses(tick) for tick in range(ticks)]
    shape = (ticks, len(replay.bodies))
    return ReplayedScene(
        bodies=tuple(replay.bodies),
        geoms=tuple(replay.geoms),
        time=np.asarray(rollout.time, dtype=float)[:ticks],
        positions=np.array([p for p, _ in poses], dtype=float).reshape(*shape, 3),
        quaternions=np.array([q for _, q in poses], dtype=float).reshape(*shape, 4),
    ), ""


def geom_centres(scene: ReplayedScene) -> np.ndarray:
    """Every geom's centre in the world on every tick, planes left out (they have no extent)."""
    index = {body: i for i, body in enumerate(scene.bodies)}
    centres = [
        scene.positions[:, index[g.body]] + _rotate(scene.quaternions[:, index[g.body]], g.pos)
        for g in scene.geoms
        if g.kind != "plane"
    ]
    return np.concatenate([np.zeros((0, 3)), *centres])


def log_scene(rec: Any, scene: ReplayedScene, *, episode: str = "") -> None:
    """Each body's geoms once, in its frame, and its pose: per tick only if it ever moves."""
    import rerun as rr

    geoms = defaultdict(list)
    for geom in scene.geoms:
        geoms[geom.body].append(geom)
    time = rr.TimeColumn(TIMELINE, duration=scene.time)
    for i, body in enumerate(scene.bodies):
        entity = entity_path(under(episode, "world"), body)
        shapes = _shapes(geoms[body])
        if shapes:
            rec.log(f"{entity}/geoms", *shapes, static=True)
        positions, quaternions = scene.positions[:, i], scene.quaternions[:, i]
        xyzw = quaternions[:, [1, 2, 3, 0]]
        if _moves(positions) or _moves(quaternions):
            rec.send_columns(
                entity,
                indexes=[time],
                columns=rr.Transform3D.columns(
                    translation=positions, quaternion=xyzw, parent_frame=[world_frame(episode)] * len(positions)
                ),
            )
        else:
            rec.log(
                entity,
                rr.Transform3D(
                    translation=positions[0], quaternion=rr.Quaternion(xyzw=xyzw[0]), parent_frame=world_frame(episode)
                ),
                static=True,
            )


def _moves(values: np.ndarray) -> bool:
    return bool(np.abs(values - values[0]).max() > _STILL)


def _shapes(geoms: Sequence[Any]) -> list[Any]:
    """One archetype per kind of shape among one body's geoms (rerun draws each kind with its own
    archetype; several archetypes share one entity)."""
    import rerun as rr

    by_kind = defaultdict(list)
    for geom in geoms:
        by_kind[geom.kind].append(geom)
    solid = rr.components.FillMode.Solid
    shapes = []
    boxes = [_box(g) for g in by_kind["box"]] + [_plane(g) for g in by_kind["plane"]]
    if boxes:
        shapes.append(
            rr.Boxes3D(
                centers=[b[0] for b in boxes],
                half_sizes=[b[1] for b in boxes],
                quaternions=[b[2] for b in boxes],
                colors=[b[3] for b in boxes],
                fill_mode=solid,
            )
        )
    round_ = by_kind["sphere"] + by_kind["ellipsoid"]
    if round_:
        shapes.append(
            rr.Ellipsoids3D(
                centers=[g.pos for g in round_],
                quaternions=[_xyzw(g.quat) for g in round_],
                half_sizes=[(g.size[0],) * 3 if g.kind == "sphere" else g.size for g in round_],
                colors=[_rgba(g.rgba) for g in round_],
                fill_mode=solid,
            )
        )
    if by_kind["capsule"]:
        capsules = by_kind["capsule"]  # rerun's capsule starts at its translation, MuJoCo's is centred
        shapes.append(
            rr.Capsules3D(
                lengths=[2 * g.size[1] for g in capsules],
                radii=[g.size[0] for g in capsules],
                translations=[np.asarray(g.pos) - _rotate(g.quat, (0.0, 0.0, g.size[1])) for g in capsules],
                quaternions=[_xyzw(g.quat) for g in capsules],
                colors=[_rgba(g.rgba) for g in capsules],
                fill_mode=solid,
            )
        )
    if by_kind["cylinder"]:
        cylinders = by_kind["cylinder"]
        shapes.append(
            rr.Cylinders3D(
                lengths=[2 * g.size[1] for g in cylinders],
                radii=[g.size[0] for g in cylinders],
                centers=[g.pos for g in cylinders],
                quaternions=[_xyzw(g.quat) for g in cylinders],
                colors=[_rgba(g.rgba) for g in cylinders],
                fill_mode=solid,
            )
        )
    meshes = [g for g in by_kind["mesh"] if g.vertices is not None and g.faces is not None]
    if meshes:
        shapes.append(_mesh(meshes))
    return shapes


def _box(geom: Any) -> tuple[Any, ...]:
    """``(centre, half sizes, xyzw, colour)``: MuJoCo's box size is already its half sizes."""
    return geom.pos, geom.size, _xyzw(geom.quat), _rgba(geom.rgba)


def _plane(geom: Any) -> tuple[Any, ...]:
    """A plane as a thin box below it, ``_PLANE_HALF`` wide where MuJoCo's has no end (size 0)."""
    half = (geom.size[0] or _PLANE_HALF, geom.size[1] or _PLANE_HALF, _PLANE_THICKNESS / 2)
    centre = np.asarray(geom.pos) - _rotate(geom.quat, (0.0, 0.0, _PLANE_THICKNESS / 2))
    return centre, half, _xyzw(geom.quat), _rgba(geom.rgba)


def _mesh(meshes: Sequence[Any]) -> Any:
    """All of one body's meshes as one ``Mesh3D`` (one per entity), each placed in the body frame
    (``Mesh3D`` has no pose of its own) and coloured per vertex."""
    import rerun as rr

    vertices, faces, colours, offset = [], [], [], 0
    for geom in meshes:
        v = np.asarray(geom.vertices, dtype=float).reshape(-1, 3)
        vertices.append(np.asarray(geom.pos) + _rotate(geom.quat, v))
        faces.append(np.asarray(geom.faces, dtype=np.uint32).reshape(-1, 3) + offset)
        colours.append(np.tile(_rgba(geom.rgba), (len(v), 1)))
        offset += len(v)
    return rr.Mesh3D(
        vertex_positions=np.concatenate(vertices),
        triangle_indices=np.concatenate(faces),
        vertex_colors=np.concatenate(colours),
    )


def _rotate(wxyz: Any, vectors: Any) -> np.ndarray:
    """``vectors`` turned by unit quaternions ``wxyz`` (MuJoCo's order); both broadcast."""
    wxyz, vectors = np.asarray(wxyz, dtype=float), np.asarray(vectors, dtype=float)
    w, q = wxyz[..., :1], wxyz[..., 1:]
    t = 2 * np.cross(q, vectors)
    return vectors + w * t + np.cross(q, t)


def _xyzw(wxyz: Sequence[float]) -> Any:
    import rerun as rr

    w, x, y, z = wxyz
    return rr.Quaternion(xyzw=[x, y, z, w])


def _rgba(rgba: Sequence[float]) -> tuple[int, ...]:
    """MuJoCo's 0-1 colour as rerun's 0-255."""
    return tuple(round(255 * min(max(float(c), 0.0), 1.0)) for c in rgba)
