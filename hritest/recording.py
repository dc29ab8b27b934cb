"""Rerun recordings of simulated scenarios: every call to ``rerun`` in hritest lives here.

Rerun's Python API has renamed things from one release to the next (``timeless`` became
``static``, ``Scalar`` became ``Scalars``, ``set_time_*`` became ``set_time``), so keeping every
call in one module keeps an upgrade to one file. Written against rerun-sdk 0.41.

One ``.rrd`` holds one scenario, application id ``hritest``, recording id the scenario digest,
timeline ``sim_time`` in simulated seconds. Entities:

==============================  =======================================================
``world/table``                 the table (static box)
``world/regions``               the workspace regions (static boxes, labelled)
``world/goals``                 the goal objects where the scenario put them (static)
``world/robot/links``           the arm's links as capsules, every tick
``world/robot/ee``              the end effector, every tick
``world/robot/ee_path``         the end effector's whole path (static line strip)
``world/human/hand``            the human's hand, every tick (tasks with a hand)
``world/human/hand_path``       the hand's whole path (static line strip)
``belief/<goal>``               the robot's belief that the human heads for each goal
``states/<agent>``              each agent's state machine, logged when it changes
``events``                      the task's events (goal reached, replanning, ...) and the verdict
``occupancy/<agent>``           the agents' occupancy grids (static images, y up)
``scenario``                    objective, measures, metrics and theta (static document)
==============================  =======================================================
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hritest.errors import HritestError

APPLICATION_ID = "hritest"
TIMELINE = "sim_time"
LINK_RADIUS = 0.03
_ROBOT = (150, 155, 170)
_EE = (230, 60, 50)
_HAND = (230, 175, 140)
_GOAL_COLOURS = ((230, 120, 30), (60, 140, 220), (90, 180, 90), (200, 80, 200), (200, 200, 60))


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


def write_recording(path: Path, *, domain: Any, evaluation: Any, rollout: Any, recording_id: str,
                    title: str = "") -> Path:
    """Writes the ``.rrd`` of one simulated scenario (atomically: a temporary file, then a rename).

    Args:
        path: where to write it; its folder is created.
        domain: the :class:`hritest.domain.Domain` the scenario belongs to.
        evaluation: the scenario's :class:`hritest.evaluate.Evaluation`.
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
    scenario = domain.space.bind(evaluation.theta_repaired) if rollout is not None else None
    layout = _layout(domain, scenario, rollout) if rollout is not None else None
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
    try:
        rec.save(tmp, default_blueprint=_blueprint(rollout, layout))
        _log_scenario(rec, domain, evaluation, title)
        if rollout is not None:
            _log_scene(rec, layout)
            _log_arm(rec, layout, rollout)
            _log_paths(rec, rollout)
            _log_belief(rec, domain, rollout)
            _log_states(rec, rollout)
            _log_occupancy(rec, rollout)
            rec.set_time(TIMELINE, duration=float(rollout.time[-1]))
            verdict = f"FAILURE ({domain.spec.failure})" if evaluation.failure else "no failure"
            rec.log("events", rr.TextLog(f"episode ends: objective {evaluation.objective:.6g}, {verdict}",
                                         level=rr.TextLogLevel.ERROR if evaluation.failure else rr.TextLogLevel.INFO))
        rec.flush()
        rec.disconnect()
        os.replace(tmp, path)
    except OSError as exc:
        raise RecordingError(f"cannot write the recording {path}: {exc.strerror or exc}") from None
    finally:
        Path(tmp).unlink(missing_ok=True)
    return path


def _blueprint(rollout: Any, layout: Any):  # noqa: ANN202 - rerun.blueprint.Blueprint
    """3D scene on the left; belief, states and events, and grids or the scenario on the right."""
    import rerun.blueprint as rrb

    eye = None
    if layout is not None:  # look at the table from above its +x, -y corner
        table = np.array(layout.table.center) + [0.0, 0.0, layout.table.half_size[2]]
        eye = rrb.EyeControls3D(position=table + [0.85, -0.75, 0.6], look_target=table, eye_up=[0.0, 0.0, 1.0])

    side = [
        rrb.TimeSeriesView(origin="belief", name="belief per goal"),
        rrb.TextLogView(origin="/", contents=["+ /states/**", "+ /events"], name="states and events"),
    ]
    grids = sorted(rollout.occupancy) if rollout is not None else []
    bottom = [rrb.Spatial2DView(origin=f"occupancy/{agent}", name=f"{agent} occupancy") for agent in grids]
    bottom.append(rrb.TextDocumentView(origin="scenario", name="scenario"))
    side.append(rrb.Tabs(*bottom))
    return rrb.Blueprint(
        rrb.Horizontal(rrb.Spatial3DView(origin="world", name="scene", eye_controls=eye), rrb.Vertical(*side),
                       column_shares=[3, 2]),
        collapse_panels=True,
    )


def _log_scenario(rec: Any, domain: Any, evaluation: Any, title: str) -> None:
    import rerun as rr

    names = [m.name for m in domain.measures]
    lines = [f"# {title or domain.spec.name}", "",
             f"status **{evaluation.status}**, failure **{evaluation.failure}** ({domain.spec.failure}), "
             f"seed {evaluation.seed}", "",
             "| quantity | value |", "|---|---|",
             f"| objective | {evaluation.objective:.6g} |",
             *(f"| {n} | {v:.6g} |" for n, v in zip(names, np.asarray(evaluation.measures, dtype=float))),
             f"| repair cost | {evaluation.repair_cost:.6g} |",
             *(f"| {k} | {v:.6g} |" for k, v in evaluation.metrics.items()),
             "", "| theta | raw | repaired |", "|---|---|---|",
             *(f"| {label} | {a:.6g} | {b:.6g} |" for label, a, b in
               zip(domain.space.labels, evaluation.theta, evaluation.theta_repaired))]
    if evaluation.message:
        lines += ["", "```", evaluation.message, "```"]
    rec.log("scenario", rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN), static=True)


def _layout(domain: Any, scenario: Any, rollout: Any):  # noqa: ANN202 - hritest.sim.WorldLayout
    from hritest.sim import world_layout

    hand = rollout.human_hand
    start = tuple(float(v) for v in hand[0]) if hand is not None and len(hand) else None
    return world_layout(domain.spec, scenario, hand_start=start)


def _log_scene(rec: Any, layout: Any) -> None:
    import rerun as rr

    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    solid = rr.components.FillMode.Solid
    rec.log("world/table", rr.Boxes3D(centers=[layout.table.center], half_sizes=[layout.table.half_size],
                                      colors=[(170, 150, 120)], fill_mode=solid, labels=["table"],
                                      show_labels=False), static=True)
    if layout.regions:
        rec.log("world/regions", rr.Boxes3D(centers=[b.center for b in layout.regions],
                                            half_sizes=[b.half_size for b in layout.regions],
                                            colors=[(120, 180, 240, 150)] * len(layout.regions), fill_mode=solid,
                                            labels=[b.name for b in layout.regions]), static=True)
    if layout.objects:
        rec.log("world/goals", rr.Boxes3D(centers=[b.center for b in layout.objects],
                                          half_sizes=[b.half_size for b in layout.objects],
                                          colors=[_GOAL_COLOURS[i % len(_GOAL_COLOURS)]
                                                  for i in range(len(layout.objects))],
                                          fill_mode=solid, labels=[b.name for b in layout.objects]), static=True)


def _log_arm(rec: Any, layout: Any, rollout: Any) -> None:
    """The arm's links per tick: a capsule from each body's frame to the next, the last to the tool."""
    import rerun as rr

    from hritest.sim import World

    try:
        world = World(layout=layout)
        world.set_q(rollout.joints[0])
    except (HritestError, ValueError) as exc:  # a user's arm the built-in world cannot pose
        rec.log("events", rr.TextLog(f"arm not drawn: {exc}", level=rr.TextLogLevel.WARN), static=True)
        return
    for t, q in zip(rollout.time, rollout.joints):
        rec.set_time(TIMELINE, duration=float(t))
        world.set_q(q)
        points = [pose[:3, 3] for pose in world.link_poses().values()] + [world.ee_pose()[:3, 3]]
        lengths, quaternions = _segments(np.array(points))
        rec.log("world/robot/links", rr.Capsules3D(lengths=lengths, radii=[LINK_RADIUS] * len(lengths),
                                                   translations=points[:-1], quaternions=quaternions,
                                                   colors=[_ROBOT] * len(lengths),
                                                   fill_mode=rr.components.FillMode.Solid))


def _segments(points: np.ndarray) -> tuple[np.ndarray, list[Any]]:
    """Length and rotation (local +z onto the segment) of each segment of a polyline."""
    import rerun as rr

    deltas = np.diff(points, axis=0)
    lengths = np.linalg.norm(deltas, axis=1)
    quaternions = []
    for delta, length in zip(deltas, lengths):
        if length < 1e-9:
            quaternions.append(rr.Quaternion(xyzw=[0.0, 0.0, 0.0, 1.0]))
            continue
        d = delta / length
        axis = np.cross([0.0, 0.0, 1.0], d)
        s = np.linalg.norm(axis)
        angle = np.arctan2(s, d[2])
        axis = axis / s if s > 1e-9 else np.array([1.0, 0.0, 0.0])
        quaternions.append(rr.Quaternion(xyzw=[*(axis * np.sin(angle / 2)), np.cos(angle / 2)]))
    return lengths, quaternions


def _log_paths(rec: Any, rollout: Any) -> None:
    import rerun as rr

    time = rr.TimeColumn(TIMELINE, duration=np.asarray(rollout.time, dtype=float))
    for entity, points, colour, radius in (("world/robot/ee", rollout.robot_ee, _EE, 0.012),
                                           ("world/human/hand", rollout.human_hand, _HAND, 0.035)):
        if points is None or not len(points):
            continue
        points = np.asarray(points, dtype=float)
        rec.log(f"{entity}_path", rr.LineStrips3D([points], radii=[0.003], colors=[colour]), static=True)
        rec.log(entity, rr.Points3D.from_fields(radii=[radius], colors=[colour]), static=True)
        rec.send_columns(entity, indexes=[time], columns=rr.Points3D.columns(positions=points))


def _log_belief(rec: Any, domain: Any, rollout: Any) -> None:
    import rerun as rr

    if rollout.belief is None or not len(rollout.belief):
        return
    belief = np.asarray(rollout.belief, dtype=float)
    names = [o.name for o in domain.spec.objects]
    time = rr.TimeColumn(TIMELINE, duration=np.asarray(rollout.time, dtype=float)[: len(belief)])
    for i in range(belief.shape[1]):
        name = names[i] if i < len(names) and belief.shape[1] == len(names) else f"goal{i}"
        colour = _GOAL_COLOURS[i % len(_GOAL_COLOURS)]
        rec.log(f"belief/{name}", rr.SeriesLines(colors=[colour], names=[name], widths=[2.0]), static=True)
        rec.send_columns(f"belief/{name}", indexes=[time], columns=rr.Scalars.columns(scalars=belief[:, i]))


def _log_states(rec: Any, rollout: Any) -> None:
    import rerun as rr

    for agent, states in rollout.states.items():
        previous = None
        for t, state in zip(rollout.time, states):
            if state != previous:
                rec.set_time(TIMELINE, duration=float(t))
                rec.log(f"states/{agent}", rr.TextLog(f"{agent}: {state}", level=rr.TextLogLevel.INFO))
                previous = state
    for t, text in rollout.events:
        rec.set_time(TIMELINE, duration=float(t))
        rec.log("events", rr.TextLog(text, level=rr.TextLogLevel.WARN))


def _log_occupancy(rec: Any, rollout: Any) -> None:
    import rerun as rr

    for agent, grid in rollout.occupancy.items():
        image = occupancy_image(grid)
        rec.log(f"occupancy/{agent}", rr.Image(image), static=True)


def occupancy_image(grid: np.ndarray) -> np.ndarray:
    """An occupancy grid (first index x) as an 8-bit image with x to the right and y up."""
    grid = np.asarray(grid, dtype=float)
    peak = grid.max() if grid.size and grid.max() > 0 else 1.0
    return (255 * np.sqrt(grid / peak)).astype(np.uint8).T[::-1].copy()


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
        subprocess.Popen([viewer, str(path)], start_new_session=True, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)
    except OSError as exc:
        raise RecordingError(f"cannot start the Rerun viewer ({viewer}): {exc.strerror or exc}; "
                             f"open the recording yourself with: rerun {path}") from None
