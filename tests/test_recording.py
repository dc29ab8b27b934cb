"""Rerun recordings of hand-built rollouts, read back from the .rrd with rerun's own reader.

The rollouts are built here, not simulated by the bundled plugins, so these tests pin what a
recording draws for each field of :class:`hritest.protocols.Rollout`, whatever the tasks report.
The scene test traces a real :class:`hritest.sim.World` and checks the recording against
:class:`hritest.sim.SceneReplay`, which poses the same world again.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

from hritest.domain import compile_spec
from hritest.protocols import Rollout
from hritest.recording import (
    APPLICATION_ID,
    TIMELINE,
    WORLD_FRAME,
    RecordingError,
    grid_image,
    recorded_entities,
    recording_ids,
    write_recording,
)
from hritest.records import Evaluation
from hritest.spec import load_spec

TOY = Path(__file__).parent / "fixtures" / "toy.yaml"
DT = 0.025


@pytest.fixture(scope="module")
def domain():
    return compile_spec(load_spec(TOY))


@pytest.fixture(scope="module")
def evaluation(domain):
    theta = np.linspace(0.0, 0.1, len(domain.space.labels))
    return Evaluation(
        theta=theta,
        theta_repaired=theta,
        repair_cost=0.0,
        regions={},
        seed=7,
        objective=9.0,
        measures=np.array([0.1, 0.02]),
        metrics={"completion_time": 9.0},
        failure=True,
    )


def record(tmp_path: Path, domain, evaluation, rollout: Rollout) -> Path:
    return write_recording(
        tmp_path / "sub" / "scenario.rrd",
        domain=domain,
        evaluation=evaluation,
        rollout=rollout,
        recording_id="digest",
        title="test",
    )


def components(path: Path, entity: str) -> tuple[dict, list[dict]]:
    """``(static row, rows in time order)`` of one entity: component name -> value."""
    static, timed = {}, {}
    for chunk in RrdReader(path).stream().to_chunks():
        if str(chunk.entity_path) != f"/{entity}":
            continue
        batch = chunk.to_record_batch()
        times = (
            batch.column(TIMELINE).cast("int64").to_pylist()
            if TIMELINE in chunk.timeline_names
            else [None] * batch.num_rows
        )
        for i, t in enumerate(times):
            row = static if t is None else timed.setdefault(t, {})
            row.update({name: batch.column(name)[i].as_py() for name in batch.schema.names if ":" in name})
    return static, [timed[t] for t in sorted(timed)]


def views(path: Path) -> list[tuple[str, str]]:
    """``(view class, origin)`` of each view of the file's default blueprint."""
    reader = RrdReader(path)
    [blueprint] = reader.blueprints()
    found = []
    for chunk in reader.stream(store=blueprint).to_chunks():
        batch = chunk.to_record_batch()
        if "ViewBlueprint:class_identifier" in batch.schema.names:
            found.append(
                (
                    batch.column("ViewBlueprint:class_identifier")[0].as_py()[0],
                    batch.column("ViewBlueprint:space_origin")[0].as_py()[0],
                )
            )
    return sorted(found)


def test_a_rollout_of_only_metrics_records_the_scenario_and_the_verdict(tmp_path, domain, evaluation):
    rollout = Rollout(dt=DT, time=np.arange(40) * DT, metrics={"completion_time": 9.0})
    path = record(tmp_path, domain, evaluation, rollout)
    entities = recorded_entities(path)
    assert {"scenario", "events"} <= set(entities)
    assert not any(e.startswith(("world", "series", "states", "grids")) for e in entities)
    assert entities["scenario"] == []
    assert entities["events"] == [pytest.approx(39 * DT)]  # the verdict, at the episode's end
    _, [verdict] = components(path, "events")
    assert verdict["TextLog:text"][0].startswith("episode ends: objective 9, FAILURE (objective >= 8)")
    document, _ = components(path, "scenario")
    assert "| goal_distance | 0.1 |" in document["TextDocument:text"][0]
    assert views(path) == [("TextDocument", "scenario"), ("TextLog", "/")]  # no empty 3D or series view
    assert recording_ids(path) == [(APPLICATION_ID, "digest")]
    assert not list(path.parent.glob(".*")), "no temporary file is left behind"


@pytest.fixture(scope="module")
def full(tmp_path_factory, domain, evaluation):
    time = np.arange(12) * DT
    rollout = Rollout(
        dt=DT,
        time=time,
        metrics={"completion_time": 9.0},
        trajectories={
            "robot/ee": np.linspace([0.4, 0.3, 0.9], [0.6, 0.0, 1.0], 12),
            "human/hand": np.linspace([1.0, 0.0, 1.0], [0.7, 0.1, 0.95], 12),
        },
        series={"belief/goal0": np.linspace(0.5, 1.0, 10), "distance": np.linspace(1.0, 0.0, 12)},
        states={"robot": ["idle"] * 3 + ["reach"] * 6 + ["done"] * 3, "human": ["walk"] * 12},
        events=[(0.1, "reached goal0")],
        grids={"robot": np.arange(16.0).reshape(4, 4), "human": np.eye(4)},
    )
    return record(tmp_path_factory.mktemp("full"), domain, evaluation, rollout), rollout


def test_trajectories_are_a_point_per_tick_and_a_static_path_in_the_world_frame(full):
    path, rollout = full
    entities = recorded_entities(path)
    for name, points in rollout.trajectories.items():
        static, rows = components(path, f"world/{name}")
        assert len(rows) == len(rollout.time)
        np.testing.assert_allclose(rows[-1]["Points3D:positions"], points[-1:], atol=1e-6)
        assert static["CoordinateFrame:frame"] == [WORLD_FRAME]  # not under a body named "robot"
        assert entities[f"world/{name}/path"] == []
        path_row, _ = components(path, f"world/{name}/path")
        np.testing.assert_allclose(path_row["LineStrips3D:strips"][0], points, atol=1e-6)


def test_series_are_scalars_over_their_own_ticks(full):
    path, rollout = full
    for name, values in rollout.series.items():
        _, rows = components(path, f"series/{name}")
        np.testing.assert_allclose([row["Scalars:scalars"][0] for row in rows], values)
    assert recorded_entities(path)["series/belief/goal0"][-1] == pytest.approx(9 * DT)


def test_states_are_logged_on_change_and_events_end_with_the_verdict(full):
    path, _ = full
    entities = recorded_entities(path)
    assert entities["states/robot"] == [0.0, pytest.approx(3 * DT), pytest.approx(9 * DT)]
    assert entities["states/human"] == [0.0]
    _, events = components(path, "events")
    assert events[0]["TextLog:text"] == ["reached goal0"]
    assert entities["events"] == [pytest.approx(0.1), pytest.approx(11 * DT)]


def test_grids_are_static_images_with_y_up(full):
    path, rollout = full
    for name, grid in rollout.grids.items():
        static, rows = components(path, f"grids/{name}")
        assert rows == []
        [form], [buffer] = static["Image:format"], static["Image:buffer"]
        image = np.array(buffer, dtype=np.uint8).reshape(form["height"], form["width"])
        np.testing.assert_array_equal(image, grid_image(grid))


def test_the_blueprint_has_a_view_for_each_kind_of_data(full):
    path, _ = full
    assert views(path) == [
        ("2D", "/grids/human"),
        ("2D", "/grids/robot"),
        ("3D", "world"),
        ("TextDocument", "scenario"),
        ("TextLog", "/"),
        ("TimeSeries", "series"),
    ]


def test_grid_image_puts_x_right_and_y_up():
    grid = np.zeros((32, 32))
    grid[31, 0] = 1.0  # high x, low y
    image = grid_image(grid)
    assert image.dtype == np.uint8 and image.shape == (32, 32)
    assert image[31, 31] == 255  # bottom row (low y), right column (high x)


def test_an_unwritable_recording_path_is_a_clear_error(tmp_path, domain, evaluation):
    rollout = Rollout(dt=DT, time=np.arange(3) * DT, metrics={})
    (tmp_path / "file").write_text("not a folder")
    with pytest.raises(RecordingError, match="cannot write the recording"):
        write_recording(
            tmp_path / "file" / "x.rrd", domain=domain, evaluation=evaluation, rollout=rollout, recording_id="x"
        )
    with pytest.raises(RecordingError, match="is a folder"):
        write_recording(tmp_path, domain=domain, evaluation=evaluation, rollout=rollout, recording_id="x")


# The scene: a real world traced for a few ticks, recorded, and compared with its replay.

TICKS = 6


@pytest.fixture(scope="module")
def scene(tmp_path_factory, domain, evaluation):
    from hritest.sim import SceneReplay, World
    from hritest.sim.layout import Box, WorldLayout

    layout = WorldLayout(
        table=Box(name="table", center=(0.6, 0.05, 0.845), half_size=(0.2, 0.3, 0.021)),
        objects=(Box(name="goal0", center=(0.6, 0.1, 0.9), half_size=(0.03, 0.03, 0.03)),),
        hand_start=(0.9, 0.0, 1.0),
    )
    world = World(layout=layout)
    tracer = world.tracer()
    for tick in range(TICKS):
        world.set_q(world.q + 0.05 * tick)
        world.set_hand((0.9 - 0.02 * tick, 0.0, 1.0))
        tracer.capture()
    # Two ticks more than the trace: the recording poses the bodies over the shorter of the two.
    rollout = Rollout(dt=DT, time=np.arange(TICKS + 2) * DT, metrics={}, scene=tracer.finish())
    path = record(tmp_path_factory.mktemp("scene"), domain, evaluation, rollout)
    return path, SceneReplay(trace=rollout.scene), rollout


def test_every_body_is_drawn_with_its_geoms(scene):
    path, replay, _ = scene
    entities = recorded_entities(path)
    for body in {g.body for g in replay.geoms}:
        assert entities[f"world/{body}/geoms"] == [], body
        geoms = [g for g in replay.geoms if g.body == body]
        kinds = Counter(g.kind for g in geoms)
        shapes, _ = components(path, f"world/{body}/geoms")
        assert len(shapes.get("Boxes3D:half_sizes", [])) == kinds["box"] + kinds["plane"]
        assert len(shapes.get("Ellipsoids3D:half_sizes", [])) == kinds["sphere"] + kinds["ellipsoid"]
        assert len(shapes.get("Cylinders3D:lengths", [])) == kinds["cylinder"]
        assert ("Mesh3D:vertex_positions" in shapes) == (kinds["mesh"] > 0)
        capsules = [g for g in geoms if g.kind == "capsule"]
        assert len(shapes.get("Capsules3D:lengths", [])) == len(capsules)
        for capsule, start, xyzw, length in zip(
            capsules,
            shapes.get("Capsules3D:translations", []),
            shapes.get("Capsules3D:quaternions", []),
            shapes.get("Capsules3D:lengths", []),
        ):
            middle = np.array(start) + _rotate(xyzw, [0.0, 0.0, length / 2])  # rerun's starts at one end
            np.testing.assert_allclose(middle, capsule.pos, atol=1e-5)
    assert views(path) == [("3D", "world"), ("TextDocument", "scenario"), ("TextLog", "/")]  # no series view


def test_moving_bodies_follow_the_replayed_poses_and_still_ones_are_static(scene):
    path, replay, _ = scene
    poses = [replay.poses(tick) for tick in range(TICKS)]
    moving = 0
    for i, body in enumerate(replay.bodies):
        static, rows = components(path, f"world/{body}")
        positions = np.array([p[i] for p, _ in poses])
        quaternions = np.array([q[i][[1, 2, 3, 0]] for _, q in poses])  # wxyz -> xyzw
        if np.ptp(positions, axis=0).max() > 1e-9 or np.ptp(quaternions, axis=0).max() > 1e-9:
            moving += 1
            assert len(rows) == TICKS, body
            np.testing.assert_allclose([r["Transform3D:translation"][0] for r in rows], positions, atol=1e-6)
            np.testing.assert_allclose([r["Transform3D:quaternion"][0] for r in rows], quaternions, atol=1e-6)
            assert {r["Transform3D:parent_frame"][0] for r in rows} == {WORLD_FRAME}
        else:
            assert rows == [], f"{body} never moves and should be static"
            np.testing.assert_allclose(static["Transform3D:translation"][0], positions[0], atol=1e-6)
            assert static["Transform3D:parent_frame"] == [WORLD_FRAME]
    assert moving >= 2  # the arm's links and the hand


def test_a_scene_that_no_longer_compiles_is_left_out_with_a_warning(tmp_path, domain, evaluation, scene):
    _, _, rollout = scene
    broken = replace(rollout.scene, qpos=rollout.scene.qpos[:, :-1])  # as if the arm file changed since
    path = record(tmp_path, domain, evaluation, replace(rollout, scene=broken))
    assert not any(e.startswith("world") for e in recorded_entities(path))
    static, [verdict] = components(path, "events")
    assert static["TextLog:text"][0].startswith("scene not drawn: The scene trace holds")
    assert verdict["TextLog:text"][0].startswith("episode ends")
    assert ("3D", "world") not in views(path)


def _rotate(xyzw, v) -> np.ndarray:
    x, y, z, w = xyzw
    q = np.array([x, y, z])
    v = np.asarray(v, dtype=float)
    return v + 2 * np.cross(q, np.cross(q, v) + w * v)
