"""Writes the ``.rrd`` of one scenario: the blueprint, the scenario document, and what the rollout
reported (trajectories, series, states and events, grids, the verdict)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hritest.recording.bodies import ReplayedScene, geom_centres, log_scene, replay_scene
from hritest.recording.entities import APPLICATION_ID, TIMELINE, entity_path, under, world_frame
from hritest.recording.files import RecordingError, check_writable

_CAMERA = np.array([0.8, -0.7, 0.55])  # eye offset per metre of the scene's diagonal: a +x, -y, +z corner
_MIN_EXTENT = 0.5  # m: the camera keeps this far back from a scene of one point
# Trajectories are drawn in screen pixels, not metres: a scene may be a 30 cm table or a 20 m corridor.
_POINT_PIXELS = 5.0
_PATH_PIXELS = 1.5
_COLOURS = ((230, 60, 50), (60, 140, 220), (90, 180, 90), (200, 80, 200), (230, 120, 30), (230, 175, 140))


@dataclass(frozen=True)
class Episode:
    """One simulated scenario of a recording: ``name`` roots its entities (``""``: a recording of
    one episode, whose entities are ``world``, ``series``, ...; else ``name/world``, ...)."""

    name: str
    evaluation: Any
    rollout: Any
    title: str = ""


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
    episode = Episode("", evaluation, rollout, title)
    return write_episodes(path, domain=domain, episodes=[episode], recording_id=recording_id)


def write_episodes(path: Path, *, domain: Any, episodes: Sequence[Episode], recording_id: str) -> Path:
    """Writes several scenarios of ``domain`` into one ``.rrd`` on one timeline, each under its
    episode's name and in a 3D view of its own side by side (a failure and the scenario nearest
    to it that passes: where they diverge is where the time cursor shows them apart); else as
    :func:`write_recording`.

    Raises:
        RecordingError: ``path`` cannot be written.
    """
    import rerun as rr

    path = check_writable(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    scenes = [replay_scene(e.rollout) for e in episodes]
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
    try:
        blueprint = (
            _blueprint(episodes[0].rollout, scenes[0][0]) if len(episodes) == 1 else _side_by_side(episodes, scenes)
        )
        rec.save(tmp, default_blueprint=blueprint)
        for episode, (scene, problem) in zip(episodes, scenes):
            _log_episode(rec, domain, episode, scene, problem)
        rec.flush()
        rec.disconnect()
        os.replace(tmp, path)
    except OSError as exc:
        raise RecordingError(f"cannot write the recording {path}: {exc.strerror or exc}") from None
    finally:
        Path(tmp).unlink(missing_ok=True)
    return path


def _log_episode(rec: Any, domain: Any, episode: Episode, scene: ReplayedScene | None, problem: str) -> None:
    import rerun as rr

    name, rollout = episode.name, episode.rollout
    _log_scenario(rec, domain, episode.evaluation, episode.title, name)
    if rollout is None:
        return
    if problem:
        rec.log(
            under(name, "events"), rr.TextLog(f"scene not drawn: {problem}", level=rr.TextLogLevel.WARN), static=True
        )
    if scene is not None or rollout.trajectories:
        rec.log(under(name, "world"), rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    if scene is not None:
        log_scene(rec, scene, episode=name)
    _log_trajectories(rec, rollout, name)
    _log_series(rec, rollout, name)
    _log_states_and_events(rec, rollout, name)
    _log_grids(rec, rollout, name)
    _log_verdict(rec, domain, episode.evaluation, rollout, name)


def _blueprint(rollout: Any, scene: ReplayedScene | None):  # noqa: ANN202 - rerun.blueprint.Blueprint
    """The 3D world on the left when there is one; series, states and events, and grids or the
    scenario on the right. A view is only there if the rollout has something for it."""
    import rerun.blueprint as rrb

    side = []
    if rollout is not None and rollout.series:
        side.append(rrb.TimeSeriesView(origin="series", name="series"))
    side.append(rrb.TextLogView(origin="/", contents=["+ /states/**", "+ /events"], name="states and events"))
    grids = [
        rrb.Spatial2DView(origin=entity_path("grids", name), name=name)
        for name in (sorted(rollout.grids) if rollout is not None else [])
    ]
    side.append(rrb.Tabs(*grids, rrb.TextDocumentView(origin="scenario", name="scenario")))
    if rollout is None or (scene is None and not rollout.trajectories):
        return rrb.Blueprint(rrb.Vertical(*side), collapse_panels=True)
    view = rrb.Spatial3DView(origin="world", name="world", eye_controls=_eye(scene, rollout))
    return rrb.Blueprint(rrb.Horizontal(view, rrb.Vertical(*side), column_shares=[3, 2]), collapse_panels=True)


def _side_by_side(episodes: Sequence[Episode], scenes: Sequence[tuple[ReplayedScene | None, str]]):  # noqa: ANN202 - rerun.blueprint.Blueprint, imported lazily
    """Each episode's world side by side above one plot of every episode's series and one log."""
    import rerun.blueprint as rrb

    worlds = [
        rrb.Spatial3DView(origin=under(e.name, "world"), name=e.name, eye_controls=_eye(scene, e.rollout))
        for e, (scene, _) in zip(episodes, scenes)
        if e.rollout is not None
    ]
    below = [
        rrb.TimeSeriesView(origin="/", contents=[f"+ /{under(e.name, 'series')}/**" for e in episodes], name="series"),
        rrb.TextLogView(
            origin="/",
            contents=[
                c for e in episodes for c in (f"+ /{under(e.name, 'states')}/**", f"+ /{under(e.name, 'events')}")
            ],
            name="states and events",
        ),
        rrb.Tabs(*(rrb.TextDocumentView(origin=under(e.name, "scenario"), name=e.name) for e in episodes)),
    ]
    return rrb.Blueprint(
        rrb.Vertical(rrb.Horizontal(*worlds), rrb.Horizontal(*below), row_shares=[3, 2]), collapse_panels=True
    )


def _eye(scene: ReplayedScene | None, rollout: Any):  # noqa: ANN202 - rerun.blueprint.archetypes.EyeControls3D
    """A camera on the scene's bounding box from its +x, -y, +z corner, the box taken over the
    whole episode (geom centres and trajectories), so that nothing that moves leaves the frame."""
    import rerun.blueprint as rrb

    points = [geom_centres(scene)] if scene is not None else []
    points += [np.asarray(p, dtype=float).reshape(-1, 3) for p in rollout.trajectories.values()]
    points = np.concatenate([np.zeros((0, 3)), *points])
    points = points[np.isfinite(points).all(axis=1)]
    if not len(points):
        return None
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = (lo + hi) / 2
    extent = max(float(np.linalg.norm(hi - lo)), _MIN_EXTENT)
    return rrb.EyeControls3D(position=centre + extent * _CAMERA, look_target=centre, eye_up=[0.0, 0.0, 1.0])


def _log_scenario(rec: Any, domain: Any, evaluation: Any, title: str, episode: str) -> None:
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
    rec.log(
        under(episode, "scenario"), rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN), static=True
    )


def _log_trajectories(rec: Any, rollout: Any, episode: str) -> None:
    """A point per tick and the whole path, both in the world frame whatever the name's parents."""
    import rerun as rr

    for i, (name, given) in enumerate(rollout.trajectories.items()):
        points = np.asarray(given, dtype=float).reshape(-1, 3)[: len(rollout.time)]
        if not len(points):
            continue
        entity, colour = entity_path(under(episode, "world"), name), _COLOURS[i % len(_COLOURS)]
        rec.log(
            entity,
            rr.CoordinateFrame(world_frame(episode)),
            rr.Points3D.from_fields(radii=rr.components.Radius.ui_points([_POINT_PIXELS]), colors=[colour]),
            static=True,
        )
        rec.log(
            f"{entity}/path",
            rr.CoordinateFrame(world_frame(episode)),
            rr.LineStrips3D([points], radii=rr.components.Radius.ui_points([_PATH_PIXELS]), colors=[colour]),
            static=True,
        )
        time = rr.TimeColumn(TIMELINE, duration=np.asarray(rollout.time, dtype=float)[: len(points)])
        rec.send_columns(entity, indexes=[time], columns=rr.Points3D.columns(positions=points))


def _log_series(rec: Any, rollout: Any, episode: str) -> None:
    import rerun as rr

    for name, given in rollout.series.items():
        values = np.asarray(given, dtype=float).reshape(-1)[: len(rollout.time)]
        entity = entity_path(under(episode, "series"), name)
        label = f"{episode}: {name}" if episode else name
        rec.log(entity, rr.SeriesLines(names=[label]), static=True)
        time = rr.TimeColumn(TIMELINE, duration=np.asarray(rollout.time, dtype=float)[: len(values)])
        rec.send_columns(entity, indexes=[time], columns=rr.Scalars.columns(scalars=values))


def _log_states_and_events(rec: Any, rollout: Any, episode: str) -> None:
    import rerun as rr

    for agent, states in rollout.states.items():
        previous = None
        for t, state in zip(rollout.time, states):
            if state != previous:
                rec.set_time(TIMELINE, duration=float(t))
                rec.log(
                    entity_path(under(episode, "states"), agent),
                    rr.TextLog(f"{agent}: {state}", level=rr.TextLogLevel.INFO),
                )
                previous = state
    for t, text in rollout.events:
        rec.set_time(TIMELINE, duration=float(t))
        rec.log(under(episode, "events"), rr.TextLog(text, level=rr.TextLogLevel.WARN))


def _log_grids(rec: Any, rollout: Any, episode: str) -> None:
    import rerun as rr

    for name, grid in rollout.grids.items():
        rec.log(entity_path(under(episode, "grids"), name), rr.Image(grid_image(grid)), static=True)


def _log_verdict(rec: Any, domain: Any, evaluation: Any, rollout: Any, episode: str) -> None:
    """The verdict as the last event, at the episode's end, so the log ends on it."""
    import rerun as rr

    end = float(rollout.time[-1]) if len(rollout.time) else 0.0
    verdict = f"FAILURE ({domain.spec.failure})" if evaluation.failure else "no failure"
    rec.set_time(TIMELINE, duration=end)
    rec.log(
        under(episode, "events"),
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
