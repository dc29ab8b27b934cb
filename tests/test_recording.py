"""Rerun recordings of real simulations, read back from the .rrd with rerun's own reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

from hritest.domain import compile_spec
from hritest.evaluate import evaluate_with_rollout
from hritest.recording import (
    APPLICATION_ID,
    TIMELINE,
    RecordingError,
    occupancy_image,
    recorded_entities,
    recording_ids,
    write_recording,
)
from hritest.replay import scenario_digest
from hritest.spec import load_spec

SPECS = Path(__file__).parent.parent / "specs"
TELEOP_THETA = [0.6, 0.05, 0.6, 0.09, 0.0, 0.01, -0.01, 0.0, 0.0]  # reaches goal0 in a few seconds
# Three boxes already inside the regions (nothing to repair); the team takes about 29 s.
COLLAB_THETA = [0.6796, 0.1265, 0.52, 0.1192, 0.5417, -0.0455]


def record(tmp_path: Path, spec: str, theta: list[float], seed: int = 0):  # noqa: ANN201
    domain = compile_spec(load_spec(SPECS / spec))
    evaluation, rollout = evaluate_with_rollout(domain, np.array(theta), seed=seed)
    assert evaluation.ok, evaluation.message
    digest = scenario_digest("spec-digest", evaluation.theta_repaired, seed)
    path = write_recording(tmp_path / "sub" / "scenario.rrd", domain=domain, evaluation=evaluation, rollout=rollout,
                           recording_id=digest, title="test")
    return path, rollout, digest


@pytest.fixture(scope="module")
def teleop(tmp_path_factory):  # noqa: ANN201
    return record(tmp_path_factory.mktemp("teleop"), "teleop.yaml", TELEOP_THETA)


def test_teleop_recording_holds_the_scene_arm_belief_and_scenario(teleop):
    path, rollout, digest = teleop
    entities = recorded_entities(path)
    for static in ("world/table", "world/regions", "world/goals", "world/robot/ee_path", "scenario",
                   "occupancy/robot"):
        assert static in entities, static
        assert entities[static] == [], f"{static} should be static"
    end = float(rollout.time[-1])
    for moving in ("world/robot/links", "world/robot/ee"):
        times = entities[moving]
        assert len(times) == len(rollout.time)
        assert times[0] == 0.0 and times[-1] == pytest.approx(end)
    assert end > 1.0  # the episode is seconds long, not one tick
    for goal in ("belief/goal0", "belief/goal1"):
        assert len(entities[goal]) == len(rollout.belief)
    assert len(entities["events"]) == len(rollout.events) + 1  # "reached goal0", then the verdict
    assert entities["events"][-1] == pytest.approx(end)
    assert recording_ids(path) == [(APPLICATION_ID, digest)]
    assert RrdReader(path).blueprints(), "the file carries its default blueprint"
    assert not list(path.parent.glob(".*")), "no temporary file is left behind"


def test_arm_capsules_form_a_chain_ending_at_the_end_effector(teleop):
    path, rollout, _ = teleop
    rows = {}
    for chunk in RrdReader(path).stream().to_chunks():
        if str(chunk.entity_path) in ("/world/robot/links", "/world/robot/ee") and TIMELINE in chunk.timeline_names:
            batch = chunk.to_record_batch()
            times = batch.column(TIMELINE).cast("int64").to_pylist()
            for i, t in enumerate(times):
                row = rows.setdefault(t, {})
                for name in batch.schema.names:
                    if ":" in name:
                        row[name] = batch.column(name)[i].as_py()
    tick = len(rollout.time) // 2
    row = rows[int(round(float(rollout.time[tick]) * 1e9))]
    starts = np.array(row["Capsules3D:translations"])
    lengths = np.array(row["Capsules3D:lengths"])
    ends = np.array([start + _rotate(q, [0.0, 0.0, length]) for start, q, length in
                     zip(starts, row["Capsules3D:quaternions"], lengths)])
    assert len(lengths) >= 6 and np.all(lengths > 0)
    np.testing.assert_allclose(ends[:-1], starts[1:], atol=1e-5)  # each link starts where the last ended
    np.testing.assert_allclose(ends[-1], rollout.robot_ee[tick], atol=1e-5)  # and the last at the tool
    np.testing.assert_allclose(row["Points3D:positions"][0], rollout.robot_ee[tick], atol=1e-6)


def _rotate(xyzw, v) -> np.ndarray:  # noqa: ANN001
    x, y, z, w = xyzw
    q = np.array([x, y, z])
    v = np.asarray(v, dtype=float)
    return v + 2 * np.cross(q, np.cross(q, v) + w * v)


def test_collaboration_recording_has_the_hand_states_and_both_grids(tmp_path):
    path, rollout, _ = record(tmp_path, "collab.yaml", COLLAB_THETA, seed=542567736)
    entities = recorded_entities(path)
    end = float(rollout.time[-1])
    assert len(entities["world/human/hand"]) == len(rollout.time)
    assert entities["world/human/hand"][-1] == pytest.approx(end)
    assert "world/human/hand_path" in entities
    for agent in ("human", "robot"):
        states = rollout.states[agent]
        changes = 1 + sum(a != b for a, b in zip(states, states[1:]))
        assert len(entities[f"states/{agent}"]) == changes  # logged on change only
        assert f"occupancy/{agent}" in entities
    assert {f"belief/goal{i}" for i in range(3)} <= set(entities)
    assert len(entities["events"]) == len(rollout.events) + 1  # and the verdict at the end


def test_occupancy_image_puts_x_right_and_y_up():
    grid = np.zeros((32, 32))
    grid[31, 0] = 1.0  # high x, low y
    image = occupancy_image(grid)
    assert image.dtype == np.uint8 and image.shape == (32, 32)
    assert image[31, 31] == 255  # bottom row (low y), right column (high x)


def test_an_unwritable_recording_path_is_a_clear_error(tmp_path, teleop):
    _, rollout, _ = teleop
    (tmp_path / "file").write_text("not a folder")
    domain = compile_spec(load_spec(SPECS / "teleop.yaml"))
    evaluation, _ = evaluate_with_rollout(domain, np.array(TELEOP_THETA), seed=0)
    with pytest.raises(RecordingError, match="cannot write the recording"):
        write_recording(tmp_path / "file" / "x.rrd", domain=domain, evaluation=evaluation, rollout=rollout,
                        recording_id="x")
    with pytest.raises(RecordingError, match="is a folder"):
        write_recording(tmp_path, domain=domain, evaluation=evaluation, rollout=rollout, recording_id="x")
