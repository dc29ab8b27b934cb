"""Rerun recordings of simulated scenarios: every call to ``rerun`` in hritest lives here.

Rerun's Python API has renamed things from one release to the next (``timeless`` became
``static``, ``Scalar`` became ``Scalars``, ``set_time_*`` became ``set_time``), so keeping every
call in one module keeps an upgrade to one file. Written against rerun-sdk 0.41.

A recording draws what the task simulated and reported in its :class:`hritest.protocols.Rollout`,
nothing rebuilt from the spec: it assumes no table, goal or arm. One ``.rrd`` holds one scenario,
application id ``hritest``, recording id the scenario digest, timeline ``sim_time`` in simulated
seconds. Names from the rollout keep their ``/`` (it groups entities in the viewer); each part
is escaped. Entities:

==============================  =======================================================
``world``                       right-handed, z up; the 3D view's origin
``world/<body>``                each body of the traced MuJoCo world (``Rollout.scene``):
                                its world pose (``Transform3D`` into ``tf#/world``), per
                                tick for bodies that move, once (static) for the others
``world/<body>/geoms``          its geoms, in its frame (static): boxes and planes as
                                ``Boxes3D``, spheres and ellipsoids as ``Ellipsoids3D``,
                                ``Capsules3D``, ``Cylinders3D``, meshes as one ``Mesh3D``
``world/<name>``                each of ``Rollout.trajectories``: a point per tick
``world/<name>/path``           its whole path (static line strip)
``series/<name>``               each of ``Rollout.series``: a scalar per tick
``states/<agent>``              each agent's state machine, logged when it changes
``events``                      the task's events, and the verdict at the episode's end
``grids/<name>``                each of ``Rollout.grids`` (static image, x right, y up)
``scenario``                    objective, measures, metrics and theta (static document)
==============================  =======================================================

Bodies and trajectories are placed in the ``world`` frame explicitly (``parent_frame`` and
``CoordinateFrame``), not through the entity tree: a body ``arm/link3`` or a trajectory
``robot/ee`` must not inherit the pose of a body called ``arm`` or ``robot``.
"""

from __future__ import annotations

import os
import tempfile
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hritest.errors import HritestError

APPLICATION_ID = "hritest"
TIMELINE = "sim_time"
WORLD_FRAME = "tf#/world"  # rerun's implicit frame of the entity ``world``
_STILL = 1e-9  # a body whose pose never changes more than this (m, quaternion units) is static
_PLANE_HALF = 5.0  # m: MuJoCo draws a plane of size 0 without end; a recording needs an edge
_PLANE_THICKNESS = 0.002  # m: a plane is drawn as a thin box whose top face is the plane
_CAMERA = np.array([0.8, -0.7, 0.55])  # eye offset per metre of the scene's diagonal: a +x, -y, +z corner
_MIN_EXTENT = 0.5  # m: the camera keeps this far back from a scene of one point
# Trajectories are drawn in screen pixels, not metres: a scene may be a 30 cm table or a 20 m corridor.
_POINT_PIXELS = 5.0
_PATH_PIXELS = 1.5
_COLOURS = ((230, 60, 50), (60, 140, 220), (90, 180, 90), (200, 80, 200), (230, 120, 30), (230, 175, 140))


class RecordingError(HritestError):
    """A recording that cannot be written where it was asked for."""


def check_writable(path: Path) -> Path:
    """Makes ``path``'s folder and checks that a file can be created there.

    Raises:
        RecordingError: the folder cannot be made or written, or ``path`` is a folder.
    """
    path = Path(path)
    if path.is_dir():
        raise RecordingError(f"{path} is a folder; give a file path for the recording, e.g. {path / 'failure.rrd'}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise RecordingError(f"cannot write the recording {path}: {exc.strerror or exc}") from None
    return path


@dataclass(frozen=True)
class _Scene:
    """The traced world replayed once, so that the blueprint's camera and the log share the poses."""

    bodies: tuple[str, ...]
    geoms: tuple[Any, ...]  # hritest.sim.Geom
    time: np.ndarray  # (ticks,) seconds
    positions: np.ndarray  # (ticks, bodies, 3) world frame
    quaternions: np.ndarray  # (ticks, bodies, 4) wxyz, world frame


def write_recording(
    path: Path, *, domain: Any, evaluation: Any, rollout: Any, recording_id: str, title: str = ""
) -> Path:
    """Writes the ``.rrd`` of one simulated scenario (atomically: a temporary file, then a rename).

    Args:
        path: where to write it; its folder is created.
        domain: the :class:`hritest.domain.Domain` the scenario belongs to (for the document:
            ``spec.name``, ``spec.failure``, ``measures``, ``space.labels``).
        evaluation: the scenario's :class:`hritest.records.Evaluation`.
        rollout: its :class:`hritest.protocols.Rollout` (``None`` if it never simulated).
        recording_id: the recording's id (the scenario digest), so that several files of one
            scenario open as one recording.
        title: a heading for the scenario document, e.g. ``"teleop failure 361"``.

    Raises:
        RecordingError: ``path`` cannot be written.
    """
    import rerun as rr

    path = check_writable(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    scene, scene_problem = _replay(rollout)
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
    try:
        rec.save(tmp, default_blueprint=_blueprint(rollout, scene))
        _log_scenario(rec, domain, evaluation, title)
        if rollout is not None:
            if scene_problem:
                rec.log(
                    "events", rr.TextLog(f"scene not drawn: {scene_problem}", level=rr.TextLogLevel.WARN), static=True
                )
            if scene is not None or rollout.trajectories:
                rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
            if scene is not None:
                _log_scene(rec, scene)
            _log_trajectories(rec, rollout)
            _log_series(rec, rollout)
            _log_states_and_events(rec, rollout)
            _log_grids(rec, rollout)
            _log_verdict(rec, domain, evaluation, rollout)
        rec.flush()
        rec.disconnect()
        os.replace(tmp, path)
    except OSError as exc:
        raise RecordingError(f"cannot write the recording {path}: {exc.strerror or exc}") from None
    finally:
        Path(tmp).unlink(missing_ok=True)
    return path


def _replay(rollout: Any) -> tuple[_Scene | None, str]:
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
    return _Scene(
        bodies=tuple(replay.bodies),
        geoms=tuple(replay.geoms),
        time=np.asarray(rollout.time, dtype=float)[:ticks],
        positions=np.array([p for p, _ in poses], dtype=float).reshape(*shape, 3),
        quaternions=np.array([q for _, q in poses], dtype=float).reshape(*shape, 4),
    ), ""


def _blueprint(rollout: Any, scene: _Scene | None):  # noqa: ANN202 - rerun.blueprint.Blueprint
    """The 3D world on the left when there is one; series, states and events, and grids or the
    scenario on the right. A view is only there if the rollout has something for it."""
    import rerun.blueprint as rrb

    side = []
    if rollout is not None and rollout.series:
        side.append(rrb.TimeSeriesView(origin="series", name="series"))
    side.append(rrb.TextLogView(origin="/", contents=["+ /states/**", "+ /events"], name="states and events"))
    grids = [
        rrb.Spatial2DView(origin=_path("grids", name), name=name)
        for name in (sorted(rollout.grids) if rollout is not None else [])
    ]
    side.append(rrb.Tabs(*grids, rrb.TextDocumentView(origin="scenario", name="scenario")))
    if rollout is None or (scene is None and not rollout.trajectories):
        return rrb.Blueprint(rrb.Vertical(*side), collapse_panels=True)
    view = rrb.Spatial3DView(origin="world", name="world", eye_controls=_eye(scene, rollout))
    return rrb.Blueprint(rrb.Horizontal(view, rrb.Vertical(*side), column_shares=[3, 2]), collapse_panels=True)


def _eye(scene: _Scene | None, rollout: Any):  # noqa: ANN202 - rerun.blueprint.archetypes.EyeControls3D
    """A camera on the scene's bounding box from its +x, -y, +z corner, the box taken over the
    whole episode (geom centres and trajectories), so that nothing that moves leaves the frame."""
    import rerun.blueprint as rrb

    points = [_geom_centres(scene)] if scene is not None else []
    points += [np.asarray(p, dtype=float).reshape(-1, 3) for p in rollout.trajectories.values()]
    points = np.concatenate([np.zeros((0, 3)), *points])
    points = points[np.isfinite(points).all(axis=1)]
    if not len(points):
        return None
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = (lo + hi) / 2
    extent = max(float(np.linalg.norm(hi - lo)), _MIN_EXTENT)
    return rrb.EyeControls3D(position=centre + extent * _CAMERA, look_target=centre, eye_up=[0.0, 0.0, 1.0])


def _geom_centres(scene: _Scene) -> np.ndarray:
    """Every geom's centre in the world on every tick, planes left out (they have no extent)."""
    index = {body: i for i, body in enumerate(scene.bodies)}
    centres = [
        scene.positions[:, index[g.body]] + _rotate(scene.quaternions[:, index[g.body]], g.pos)
        for g in scene.geoms
        if g.kind != "plane"
    ]
    return np.concatenate([np.zeros((0, 3)), *centres])


def _log_scenario(rec: Any, domain: Any, evaluation: Any, title: str) -> None:
    import rerun as rr

    names = [m.name for m in domain.measures]
    lines = [
        f"# {title or domain.spec.name}",
        "",
        f"status **{evaluation.status}**, failure **{evaluation.failure}** ({domain.spec.failure}), "
        f"seed {evaluation.seed}",
        "",
        "| quantity | value |",
        "|---|---|",
        f"| objective | {evaluation.objective:.6g} |",
        *(f"| {n} | {v:.6g} |" for n, v in zip(names, np.asarray(evaluation.measures, dtype=float))),
        f"| repair cost | {evaluation.repair_cost:.6g} |",
        *(f"| {k} | {v:.6g} |" for k, v in evaluation.metrics.items()),
        "",
        "| theta | raw | repaired |",
        "|---|---|---|",
        *(
            f"| {label} | {a:.6g} | {b:.6g} |"
            for label, a, b in zip(domain.space.labels, evaluation.theta, evaluation.theta_repaired)
        ),
    ]
    if evaluation.message:
        lines += ["", "```", evaluation.message, "```"]
    rec.log("scenario", rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN), static=True)


def _log_scene(rec: Any, scene: _Scene) -> None:
    """Each body's geoms once, in its frame, and its pose: per tick only if it ever moves."""
    import rerun as rr

    geoms = defaultdict(list)
    for geom in scene.geoms:
        geoms[geom.body].append(geom)
    time = rr.TimeColumn(TIMELINE, duration=scene.time)
    for i, body in enumerate(scene.bodies):
        entity = _path("world", body)
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
                    translation=positions, quaternion=xyzw, parent_frame=[WORLD_FRAME] * len(positions)
                ),
            )
        else:
            rec.log(
                entity,
                rr.Transform3D(
                    translation=positions[0], quaternion=rr.Quaternion(xyzw=xyzw[0]), parent_frame=WORLD_FRAME
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


def _log_trajectories(rec: Any, rollout: Any) -> None:
    """A point per tick and the whole path, both in the world frame whatever the name's parents."""
    import rerun as rr

    for i, (name, points) in enumerate(rollout.trajectories.items()):
        points = np.asarray(points, dtype=float).reshape(-1, 3)[: len(rollout.time)]
        if not len(points):
            continue
        entity, colour = _path("world", name), _COLOURS[i % len(_COLOURS)]
        rec.log(
            entity,
            rr.CoordinateFrame(WORLD_FRAME),
            rr.Points3D.from_fields(radii=rr.components.Radius.ui_points([_POINT_PIXELS]), colors=[colour]),
            static=True,
        )
        rec.log(
            f"{entity}/path",
            rr.CoordinateFrame(WORLD_FRAME),
            rr.LineStrips3D([points], radii=rr.components.Radius.ui_points([_PATH_PIXELS]), colors=[colour]),
            static=True,
        )
        time = rr.TimeColumn(TIMELINE, duration=np.asarray(rollout.time, dtype=float)[: len(points)])
        rec.send_columns(entity, indexes=[time], columns=rr.Points3D.columns(positions=points))


def _log_series(rec: Any, rollout: Any) -> None:
    import rerun as rr

    for name, values in rollout.series.items():
        values = np.asarray(values, dtype=float).reshape(-1)[: len(rollout.time)]
        entity = _path("series", name)
        rec.log(entity, rr.SeriesLines(names=[name]), static=True)
        time = rr.TimeColumn(TIMELINE, duration=np.asarray(rollout.time, dtype=float)[: len(values)])
        rec.send_columns(entity, indexes=[time], columns=rr.Scalars.columns(scalars=values))


def _log_states_and_events(rec: Any, rollout: Any) -> None:
    import rerun as rr

    for agent, states in rollout.states.items():
        previous = None
        for t, state in zip(rollout.time, states):
            if state != previous:
                rec.set_time(TIMELINE, duration=float(t))
                rec.log(_path("states", agent), rr.TextLog(f"{agent}: {state}", level=rr.TextLogLevel.INFO))
                previous = state
    for t, text in rollout.events:
        rec.set_time(TIMELINE, duration=float(t))
        rec.log("events", rr.TextLog(text, level=rr.TextLogLevel.WARN))


def _log_grids(rec: Any, rollout: Any) -> None:
    import rerun as rr

    for name, grid in rollout.grids.items():
        rec.log(_path("grids", name), rr.Image(grid_image(grid)), static=True)


def _log_verdict(rec: Any, domain: Any, evaluation: Any, rollout: Any) -> None:
    """The verdict as the last event, at the episode's end, so the log ends on it."""
    import rerun as rr

    end = float(rollout.time[-1]) if len(rollout.time) else 0.0
    verdict = f"FAILURE ({domain.spec.failure})" if evaluation.failure else "no failure"
    rec.set_time(TIMELINE, duration=end)
    rec.log(
        "events",
        rr.TextLog(
            f"episode ends: objective {evaluation.objective:.6g}, {verdict}",
            level=rr.TextLogLevel.ERROR if evaluation.failure else rr.TextLogLevel.INFO,
        ),
    )


def grid_image(grid: np.ndarray) -> np.ndarray:
    """A grid (first index x) as an 8-bit image with x to the right and y up; the square root
    brightens the rarely visited cells of an occupancy grid. Negative or NaN cells are black."""
    grid = np.nan_to_num(np.clip(np.asarray(grid, dtype=float), 0.0, None))
    peak = grid.max() if grid.size and grid.max() > 0 else 1.0
    return (255 * np.sqrt(grid / peak)).astype(np.uint8).T[::-1].copy()


def _path(root: str, name: str) -> str:
    """``root/name`` with each ``/``-separated part of ``name`` escaped for rerun."""
    import rerun as rr

    return rr.new_entity_path([root, *(part for part in str(name).split("/") if part)])


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
    return tuple(int(round(255 * min(max(float(c), 0.0), 1.0))) for c in rgba)


def recorded_entities(path: Path) -> Mapping[str, Sequence[float]]:
    """Entity path -> the ``sim_time`` points (seconds) logged to it; static entities map to ``()``.

    For tests and for checking a recording without a viewer.
    """
    from rerun.chunk import RrdReader

    found: dict[str, list[float]] = {}
    for chunk in RrdReader(Path(path)).stream().to_chunks():
        entity = str(chunk.entity_path).lstrip("/")
        times = found.setdefault(entity, [])
        if TIMELINE in chunk.timeline_names:
            column = chunk.to_record_batch().column(TIMELINE)
            times.extend(v / 1e9 for v in column.cast("int64").to_pylist() if v is not None)
    return {entity: sorted(times) for entity, times in found.items()}


def recording_ids(path: Path) -> list[tuple[str, str]]:
    """``(application_id, recording_id)`` of each recording in an ``.rrd`` file."""
    from rerun.chunk import RrdReader

    return [(e.application_id, e.recording_id) for e in RrdReader(Path(path)).recordings()]


def open_viewer(path: Path) -> None:
    """Starts the Rerun viewer on ``path`` in the background.

    Raises:
        RecordingError: the viewer cannot be started.
    """
    import shutil
    import subprocess
    import sys

    viewer = shutil.which("rerun") or str(Path(sys.executable).with_name("rerun"))
    try:
        subprocess.Popen(
            [viewer, str(path)], start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
    except OSError as exc:
        raise RecordingError(
            f"cannot start the Rerun viewer ({viewer}): {exc.strerror or exc}; "
            f"open the recording yourself with: rerun {path}"
        ) from None
