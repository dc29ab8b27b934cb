"""The handover domain (``specs/handover.yaml`` and its plugins, loaded by path) in real MuJoCo.

theta = (person_x, person_y, person_yaw, reaction_delay, patience, reach_speed, spot_forward,
spot_height, robot_speed). The arm stands on a stand at the origin (mount 0.7 m up, shoulder 1.0 m,
reach 0.78 m); its tool starts at (0.4, 0, 1.24). The person faces it from +x; the hand is held out
``spot_forward`` in front of them, 0.1 m to their right (+y), at ``spot_height``. Each scenario
simulates once per session (a few ms) and is shared by the tests.
"""

from __future__ import annotations

import shutil
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hritest import search as qd
from hritest.cli import app
from hritest.domain import compile_spec
from hritest.errors import SpecError
from hritest.evaluate import evaluate_with_rollout
from hritest.rundir import RunDirectory
from hritest.sim import SceneReplay
from hritest.spec import load_spec

SPECS = Path(__file__).parents[2] / "specs"
SPEC = SPECS / "handover.yaml"
DT = 0.025
TIME_LIMIT = 10.0

#            px    py   yaw  delay patience reach fwd   height speed
NOMINAL = (1.0, 0.0, 0.0, 0.5, 3.0, 0.5, 0.35, 1.1, 0.25)  # near, patient, quick: handed over at once
FAR = (1.2, 0.0, 0.0, 0.5, 5.0, 0.5, 0.2, 1.45, 0.35)  # the hand 1.1 m from the shoulder: out of reach
SLOW_VS_IMPATIENT = (1.0, 0.0, 0.0, 0.5, 0.5, 0.5, 0.35, 1.1, 0.1)  # 0.5 s of patience, 0.1 m/s
WITHDRAWS = (1.0, 0.0, 0.0, 0.5, 1.5, 0.5, 0.35, 1.1, 0.1)  # 1.5 s of patience against the slow robot
NEAR_THE_FACE = (0.8, 0.0, 0.0, 0.5, 3.0, 0.5, 0.2, 1.45, 0.25)  # the hand held out under the chin


@cache
def domain():
    return compile_spec(load_spec(SPEC))


@cache
def run(theta: tuple[float, ...], seed: int = 0):
    """(Evaluation, Rollout) of ``theta``, checked to have simulated."""
    evaluation, rollout = evaluate_with_rollout(domain(), np.array(theta), seed=seed)
    assert evaluation.ok, evaluation.message
    assert rollout is not None
    return evaluation, rollout


def event_times(rollout, text: str) -> list[float]:
    return [t for t, what in rollout.events if what == text]


# --- the spec -------------------------------------------------------------------------------


def test_the_spec_compiles_with_its_nine_parameters():
    d = domain()
    assert d.space.labels == [
        "person_x",
        "person_y",
        "person_yaw",
        "reaction_delay",
        "patience",
        "reach_speed",
        "spot_forward",
        "spot_height",
        "robot_speed",
    ]
    assert d.task_cls.__name__ == "HandoverTask" and d.grids == {"robot": (32, 32), "human": (32, 32)}
    np.testing.assert_allclose(d.nominal, NOMINAL)


def test_hritest_check_passes():
    result = CliRunner().invoke(app, ["check", str(SPEC)])
    assert result.exit_code == 0, result.output
    assert "ready to search" in result.output


def test_bounds_the_plugins_params_reject_are_caught_when_compiling(tmp_path):
    shutil.copy(SPECS / "handover_plugins.py", tmp_path)
    shutil.copytree(SPECS / "models", tmp_path / "models")
    text = SPEC.read_text().replace("robot.max_speed, bounds: [0.1, 0.35]", "robot.max_speed, bounds: [0.1, 1.5]")
    (tmp_path / "handover.yaml").write_text(text)
    with pytest.raises(SpecError, match=r"ReachingRobot\.Params rejects max_speed = 1\.5"):
        compile_spec(load_spec(tmp_path / "handover.yaml"))


# --- the behaviour ----------------------------------------------------------------------------


def test_a_near_patient_quick_person_gets_the_parcel():
    evaluation, rollout = run(NOMINAL)
    m = evaluation.metrics
    assert not evaluation.failure
    assert m["reached"] == 1.0 and m["withdrawals"] == 0.0
    assert m["handover_time"] < 3.0  # well below the 10 s limit
    assert event_times(rollout, "handover") == [pytest.approx(m["handover_time"])]
    assert m["min_ee_hand_distance"] < 0.05
    assert rollout.states["human"][-1] in ("reaching", "holding")


@pytest.mark.parametrize("theta", [FAR, SLOW_VS_IMPATIENT], ids=["out-of-reach", "slow-robot-impatient-person"])
def test_no_handover_for_a_person_out_of_reach_or_an_impatient_one(theta):
    evaluation, rollout = run(theta)
    m = evaluation.metrics
    assert evaluation.failure
    assert m["reached"] == 0.0 and m["handover_time"] == TIME_LIMIT and evaluation.objective == TIME_LIMIT
    assert not event_times(rollout, "handover")
    assert event_times(rollout, "time limit reached") == [pytest.approx(TIME_LIMIT)]
    assert m["min_ee_hand_distance"] > 0.05
    assert len(rollout.time) == round(TIME_LIMIT / DT) + 1


def test_out_of_reach_the_arm_stretches_towards_the_hand_and_waits_at_its_edge():
    evaluation, rollout = run(FAR)
    ee = rollout.trajectories["robot/ee"]
    stretch = np.linalg.norm(ee - np.array([0.0, 0.0, 1.0]), axis=1)  # from the shoulder
    assert 0.74 < stretch.max() <= 0.78 + 0.005  # as far out as it goes (the robot's reach: 0.78 m) ...
    assert evaluation.metrics["reach_distance"] > 1.0  # ... for a hand farther than that
    # It waits there, still, while the person holds the hand out of reach (1 s before withdrawing).
    withdrawn = round(event_times(rollout, "person withdraws the hand")[0] / DT)
    assert np.ptp(ee[withdrawn - round(1.0 / DT) : withdrawn + 1], axis=0).max() < 1e-3
    assert stretch[withdrawn] > 0.74
    assert evaluation.metrics["withdrawals"] >= 1.0
    # While the hand was withdrawn the arm went back towards where it started.
    assert "retreat" in rollout.states["robot"]


def test_the_end_effector_tracks_the_hand():
    _, rollout = run(NOMINAL)
    distance = rollout.series["distance/ee_hand"]
    ee, hand = rollout.trajectories["robot/ee"], rollout.trajectories["human/hand"]
    np.testing.assert_allclose(distance, np.linalg.norm(ee - hand, axis=1))
    reach = round(event_times(rollout, "person reaches out (attempt 1)")[0] / DT)
    assert distance[reach] > 0.25
    assert distance[-1] < 0.05
    # Once the hand has arrived at its spot, every tick brings the end effector closer.
    holding = round(event_times(rollout, "person holds the hand out")[0] / DT)
    assert np.all(np.diff(distance[holding:]) < 0)
    # Before the person reacts the robot stays where it started.
    assert np.ptp(ee[: reach + 1], axis=0).max() == 0.0
    assert set(rollout.states["robot"][: reach + 1]) == {"hold"}


def test_the_person_withdraws_after_waiting_patience_seconds_then_tries_again():
    evaluation, rollout = run(WITHDRAWS)
    patience = WITHDRAWS[4]
    held = event_times(rollout, "person holds the hand out")
    withdrawn = event_times(rollout, "person withdraws the hand")
    reached_out = event_times(rollout, "person reaches out (attempt 1)") + event_times(
        rollout, "person reaches out (attempt 2)"
    )
    assert len(withdrawn) >= 1 and len(reached_out) == 2
    assert withdrawn[0] - held[0] == pytest.approx(patience, abs=1e-9)
    assert reached_out[1] > withdrawn[0]  # withdrew (back to rest and a 1 s pause), then tried again
    states = rollout.states["human"]
    first_hold = round(held[0] / DT)
    assert states[first_hold + 1 : first_hold + round(patience / DT) + 1] == ["holding"] * round(patience / DT)
    assert evaluation.metrics["withdrawals"] == len(withdrawn)
    assert evaluation.metrics["hand_wait_time"] == pytest.approx(states.count("holding") * DT)
    # The hand went back to where it rests between the two reaches.
    hand = rollout.trajectories["human/hand"]
    np.testing.assert_allclose(hand[round(reached_out[1] / DT)], hand[0], atol=1e-9)


def test_a_later_reaction_delays_the_handover():
    early, _ = run(NOMINAL)
    late_theta = NOMINAL[:3] + (2.5,) + NOMINAL[4:]
    late, rollout = run(late_theta)
    assert late.metrics["reached"] == 1.0
    assert late.metrics["handover_time"] == pytest.approx(early.metrics["handover_time"] + 2.0, abs=0.2)
    assert event_times(rollout, "person reaches out (attempt 1)") == [pytest.approx(2.5)]


def test_a_hand_held_out_under_the_chin_brings_the_arm_too_close_to_the_head():
    evaluation, rollout = run(NEAR_THE_FACE)
    m = evaluation.metrics
    assert m["reached"] == 1.0 and m["handover_time"] < 5.0  # handed over in time, but ...
    assert m["min_head_distance"] < 0.3 and evaluation.failure  # ... too close to the face
    assert m["min_head_distance"] >= 0.2 - 0.01  # the robot slows to a stop 0.2 m from the head's centre
    assert m["min_head_distance"] == pytest.approx(rollout.series["distance/ee_head"].min())


def test_same_seed_same_outcome():
    a, ra = run(WITHDRAWS, seed=3)
    b, rb = evaluate_with_rollout(domain(), np.array(WITHDRAWS), seed=3)
    assert a.metrics == b.metrics and a.objective == b.objective
    np.testing.assert_array_equal(ra.trajectories["human/hand"], rb.trajectories["human/hand"])
    np.testing.assert_array_equal(ra.trajectories["robot/ee"], rb.trajectories["robot/ee"])
    assert ra.events == rb.events


# --- the recording ----------------------------------------------------------------------------


def person_x_in_trace(rollout, tick: int = 0) -> float:
    replay = SceneReplay(trace=rollout.scene)
    positions, _ = replay.poses(tick)
    return float(positions[replay.bodies.index("person"), 0])


def test_moving_person_x_moves_the_person_in_the_scene_trace():
    near = (0.8,) + NOMINAL[1:]
    _, r_near = run(near)
    _, r_nominal = run(NOMINAL)
    assert person_x_in_trace(r_near) == pytest.approx(0.8)
    assert person_x_in_trace(r_nominal) == pytest.approx(1.0)
    assert person_x_in_trace(r_nominal, tick=len(r_nominal.time) - 1) == pytest.approx(1.0)


def test_the_scene_trace_shows_the_hand_and_the_end_effector_where_the_trajectories_are():
    _, rollout = run(WITHDRAWS)
    replay = SceneReplay(trace=rollout.scene)
    assert replay.ticks == len(rollout.time)
    assert {"person", "stand", "side_table", "hand"} <= set(replay.bodies)
    for tick in (0, replay.ticks // 2, replay.ticks - 1):
        positions, _ = replay.poses(tick)
        np.testing.assert_allclose(
            positions[replay.bodies.index("hand")], rollout.trajectories["human/hand"][tick], atol=1e-12
        )
    # The tool's last link ends 0.05 m short of the ee site, along the tool's axis.
    positions, _ = replay.poses(replay.ticks - 1)
    link7 = positions[replay.bodies.index("arm/link7")]
    assert np.linalg.norm(link7 - rollout.trajectories["robot/ee"][-1]) == pytest.approx(0.05, abs=1e-9)


# --- a search ---------------------------------------------------------------------------------


def test_a_small_random_search_evaluates_every_scenario(tmp_path):
    qd.start(
        spec_file=SPEC,
        out=tmp_path / "run",
        algorithm="random",
        budget=60,
        seed=0,
        backend=qd.Backend(workers=2, timeout=60),
    )
    records = RunDirectory.open(tmp_path / "run").evaluations()
    assert sorted(r.index for r in records) == list(range(60))
    assert all(r.status == "ok" for r in records), [r.message for r in records if r.status != "ok"]
    assert any(r.failure for r in records) and not all(r.failure for r in records)
