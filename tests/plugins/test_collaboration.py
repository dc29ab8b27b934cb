"""Shared workspace collaboration end to end: the human's goal order, waiting, replanning, time limit.

Real MuJoCo simulation of ``specs/collab.yaml`` and ``specs/collab_human.yaml``. theta = (x0, y0, x1,
y1, x2, y2), the boxes in the human's order; ws1 is x [0.52, 0.68] y [-0.08, 0.18], ws2 x [0.138,
0.298] y [0.496, 0.756]. The human starts at (0.91, 0.05), labels goal0, goal1, goal2 (5 s each,
returning to its start in between); the robot stamps all three (3 s each, 3 s reset).
Each scenario simulates once per session (about 1-2 s each) and is shared by the tests.
"""

from __future__ import annotations

import itertools
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from hritest.domain import compile_spec
from hritest.evaluate import evaluate_with_rollout
from hritest.spec import load_spec

SPECS = Path(__file__).parents[2] / "specs"
DT = 0.025
GOALS = ("goal0", "goal1", "goal2")

ALL_WS1 = (0.55, -0.05, 0.65, 0.15, 0.55, 0.15)  # all three boxes in ws1, no waiting, no replanning
SPREAD = (0.6, 0.0, 0.2, 0.6, 0.6, 0.15)  # goal1 in ws2: the robot must swing round to the far region
# The robot stamps boxes by the feasible-goal mapping: the closest box it has not done other than the
# one it believes the human wants. Here it does goal1 (while the human does goal0), then goal0
# (human: goal1), which leaves goal2 last for both: the robot arrives while the human works on it.
ROBOT_WAITS = (0.65, -0.05, 0.55, 0.05, 0.65, 0.15)
# Here goal1 lies on the human's straight way in to goal0, so the robot believes the human heads for
# goal1, takes the closest other box, goal0, and the human arrives to find it busy.
HUMAN_WAITS = (0.55, 0.05, 0.65, 0.05, 0.65, 0.15)


@cache
def domain(path: str):
    return compile_spec(load_spec(path))


@cache
def run(theta: tuple[float, ...], spec: str = str(SPECS / "collab.yaml")):
    """(Evaluation, Rollout) of ``theta``, checked to have simulated."""
    evaluation, rollout = evaluate_with_rollout(domain(spec), np.array(theta), seed=0)
    assert evaluation.ok, evaluation.message
    assert rollout is not None
    return evaluation, rollout


def event_time(rollout, text: str) -> float:
    times = [t for t, what in rollout.events if what == text]
    assert len(times) == 1, (text, rollout.events)
    return times[0]


def blocks(states: list[str]) -> list[tuple[str, int, int]]:
    """Runs of equal states as ``(state, first tick, length)``."""
    out, tick = [], 0
    for state, run_ in itertools.groupby(states):
        n = len(list(run_))
        out.append((state, tick, n))
        tick += n
    return out


def goal_xy(theta, g: int) -> np.ndarray:
    return np.array(theta[2 * g : 2 * g + 2])


# --- the human ----------------------------------------------------------------------------


@pytest.mark.parametrize("theta", [ALL_WS1, SPREAD], ids=["all-in-ws1", "spread"])
def test_the_mdp_human_works_on_each_of_its_goals_in_order(theta):
    evaluation, rollout = run(theta)
    np.testing.assert_allclose(evaluation.theta_repaired, theta)  # already valid: repair leaves it
    human = [what for _, what in rollout.events if what.startswith("human ")]
    assert human == [f"human {verb} {g}" for g in GOALS for verb in ("starts work on", "finished")]

    working = [(start, n) for state, start, n in blocks(rollout.states["human"]) if state == "working"]
    assert len(working) == 3
    for g, (start, n) in enumerate(working):
        assert n == round(5.0 / DT)  # human_work_time
        hand = rollout.trajectories["human/hand"][start : start + n, :2]
        # At its box (the 1 cm arrival tolerance) and still while it works.
        assert np.linalg.norm(hand - goal_xy(theta, g), axis=1).max() < 0.011
        assert np.ptp(hand, axis=0).max() == 0.0
    assert rollout.states["human"][-1] == "done"


# --- waiting for a box --------------------------------------------------------------------


@pytest.mark.parametrize(
    ("theta", "waiter", "other"),
    [(ROBOT_WAITS, "robot", "human"), (HUMAN_WAITS, "human", "robot")],
    ids=["robot-waits", "human-waits"],
)
def test_both_wanting_the_same_box_makes_the_second_one_wait(theta, waiter, other):
    evaluation, rollout = run(theta)
    m = evaluation.metrics
    assert m[f"{waiter}_wait_time"] >= 1.0
    assert m[f"{other}_wait_time"] == 0.0
    assert m["total_wait_time"] == pytest.approx(m["human_wait_time"] + m["robot_wait_time"])

    # The wait is the waiting agent's "waiting" ticks ...
    states = np.array(rollout.states[waiter])
    waiting = np.flatnonzero(states == "waiting")
    assert len(waiting) * DT == pytest.approx(m[f"{waiter}_wait_time"], abs=DT + 1e-9)
    assert np.all(np.diff(waiting) == 1)  # one stretch
    # ... spent standing at a box ...
    position = (rollout.trajectories["robot/ee"] if waiter == "robot" else rollout.trajectories["human/hand"])[
        waiting, :2
    ]
    assert np.ptp(position, axis=0).max() == 0.0
    distances = [np.linalg.norm(position[0] - goal_xy(theta, g)) for g in range(3)]
    g = int(np.argmin(distances))
    assert distances[g] < 0.011
    box = GOALS[g]
    # ... while the other agent worked on that very box; the waiter took it as soon as it was free.
    t_first, t_last = waiting[0] * DT, waiting[-1] * DT
    released = event_time(rollout, f"{other} finished {box}")
    assert event_time(rollout, f"{other} starts work on {box}") <= t_first + 1e-9
    assert t_last <= released + 1e-9
    assert released - 1e-9 <= event_time(rollout, f"{waiter} starts work on {box}") <= released + DT + 1e-9


def test_without_a_shared_box_nobody_waits():
    evaluation, rollout = run(ALL_WS1)
    assert evaluation.metrics["total_wait_time"] == 0.0
    assert "waiting" not in rollout.states["human"] and "waiting" not in rollout.states["robot"]


# --- the robot's path and replanning ------------------------------------------------------


def test_goals_spread_over_both_regions_make_the_robot_path_longer():
    spread, _ = run(SPREAD)
    near, _ = run(ALL_WS1)
    assert set(spread.regions.values()) == {"ws1", "ws2"}
    assert set(near.regions.values()) == {"ws1"}
    assert spread.metrics["robot_path_length"] > near.metrics["robot_path_length"] + 0.3


def test_a_straight_line_the_arm_cannot_follow_triggers_replanning():
    """Heading for the ws2 box from its ws1-facing home, the arm's straight-line motion stalls (the
    achieved translation falls below 0.6 of the commanded one, the reference's "joint limit" test):
    the robot replans by turning its base joint by pi, and then gets there."""
    evaluation, rollout = run(SPREAD)
    replans = [t for t, what in rollout.events if what == "robot replans"]
    assert len(replans) >= 1
    assert evaluation.metrics["replans"] == len(replans)
    tick = round(replans[0] / DT)
    start_base = rollout.scene.qpos[0][0]
    turned = rollout.scene.qpos[tick + 1][0] - start_base
    assert abs(abs(turned) - np.pi) < 1e-9  # the new home faces the other workspace
    assert rollout.states["robot"][tick + 1] == "replanning"
    # After replanning it reaches and stamps the ws2 box.
    assert event_time(rollout, "robot starts work on goal1") > replans[0]
    assert np.linalg.norm(rollout.trajectories["robot/ee"][-1, :2] - goal_xy(SPREAD, 1)) < 0.011
    # Boxes all in ws1 need no replanning.
    near, near_rollout = run(ALL_WS1)
    assert near.metrics["replans"] == 0.0
    assert not any(what == "robot replans" for _, what in near_rollout.events)


def test_a_replan_pauses_the_robot_as_long_as_replan_time_like_work_and_reset():
    """replan_time, robot_work_time and robot_reset_time are all 3 s (120 ticks), as in the reference."""
    _, rollout = run(SPREAD)
    lengths: dict[str, set[int]] = {}
    for state, start, n in blocks(rollout.states["robot"])[:-1]:  # the last block is cut by the episode end
        lengths.setdefault(state, set()).add(n)
        if state == "replanning":
            assert np.ptp(rollout.trajectories["robot/ee"][start : start + n], axis=0).max() == 0.0  # it holds still
    assert lengths["working"] == {120}
    assert lengths["resetting"] == {120}
    assert lengths["replanning"] == {120}


# --- the episode's end --------------------------------------------------------------------


def test_the_episode_ends_when_both_are_done():
    evaluation, rollout = run(ALL_WS1)
    completion = evaluation.metrics["completion_time"]
    assert completion < 100.0 and evaluation.objective == completion and not evaluation.failure
    finished = [t for t, what in rollout.events if " finished " in what]
    assert len(finished) == 6  # three boxes each
    assert max(finished) <= completion <= max(finished) + DT + 1e-9
    assert rollout.time[-1] <= completion
    assert not any(what == "time limit reached" for _, what in rollout.events)


def test_an_episode_that_cannot_finish_ends_exactly_at_the_time_limit(tmp_path):
    # A human far too slow (0.005 m/s) to label three boxes in 100 s.
    text = (SPECS / "collab.yaml").read_text()
    old = "  params: {start: [0.91, 0.05]}\n"
    assert text.count(old) == 1
    spec = tmp_path / "collab_slow.yaml"
    spec.write_text(text.replace(old, "  params: {start: [0.91, 0.05], speed: 0.02}\n"))
    evaluation, rollout = run(ALL_WS1, str(spec))
    assert evaluation.metrics["completion_time"] == 100.0
    assert evaluation.objective == 100.0 and evaluation.failure  # failure: objective >= 60
    assert rollout.events[-1] == (100.0, "time limit reached")
    assert len(rollout.time) == round(100.0 / DT)
    assert rollout.states["human"][-1] != "done"


# --- human-model parameters ---------------------------------------------------------------


def test_a_faster_human_finishes_its_walking_sooner():
    spec = str(SPECS / "collab_human.yaml")
    assert list(domain(spec).space.labels[-2:]) == ["log_rationality", "speed"]
    slow, slow_rollout = run((*ALL_WS1, 3.0, 0.5), spec)
    fast, fast_rollout = run((*ALL_WS1, 3.0, 2.0), spec)

    def walking(rollout) -> float:
        return rollout.states["human"].count("moving") * DT

    assert walking(fast_rollout) < walking(slow_rollout) / 2  # 4x the speed, same route
    assert fast.metrics["human_path_length"] == pytest.approx(slow.metrics["human_path_length"], rel=0.05)
    assert event_time(fast_rollout, "human starts work on goal0") < event_time(
        slow_rollout, "human starts work on goal0"
    )
    assert event_time(fast_rollout, "human finished goal2") < event_time(slow_rollout, "human finished goal2")
    # Speed 0.5 with rationality 10^3 is the fixed human of collab.yaml: the same episode.
    fixed, _ = run(ALL_WS1)
    assert slow.objective == fixed.objective
    assert slow.metrics == fixed.metrics
