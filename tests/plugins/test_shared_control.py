"""Shared control teleoperation end to end: belief, assistance, blending, faults, the recorded episode.

Real MuJoCo simulation of ``specs/teleop.yaml`` (hindsight-optimisation assistance) and
``specs/teleop_blend.yaml`` (policy blending). theta = (g0x, g0y, g1x, g1y, noise[0..4]); goal0 is
the user's true goal and the user starts at (0.41, 0.05), heading along +x.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest

from hritest.domain import compile_spec
from hritest.evaluate import evaluate_with_rollout
from hritest.spec import load_spec

SPECS = Path(__file__).parents[2] / "specs"
NO_NOISE = (0.0,) * 5
GOAL_Z = 0.96
# Two goals far apart (0.25 m), one on each side of the user's straight path.
LOW, HIGH = (0.66, -0.06), (0.54, 0.16)


def beliefs(rollout) -> np.ndarray:
    """The robot's belief per tick, one column per goal, from the rollout's ``belief/<goal>`` series."""
    return np.column_stack([v for k, v in rollout.series.items() if k.startswith("belief/")])


@cache
def domain(name: str):
    return compile_spec(load_spec(SPECS / f"{name}.yaml"))


@cache
def run(name: str, theta: tuple[float, ...]):
    """(Evaluation, Rollout) of ``theta`` on ``specs/<name>.yaml``, checked to have simulated."""
    evaluation, rollout = evaluate_with_rollout(domain(name), np.array(theta), seed=0)
    assert evaluation.ok, evaluation.message
    assert rollout is not None
    return evaluation, rollout


def theta_of(goal0, goal1, noise=NO_NOISE) -> tuple[float, ...]:
    return (*goal0, *goal1, *noise)


def ee_speeds(rollout) -> np.ndarray:
    """End-effector speed (m/s) over each tick."""
    return np.linalg.norm(np.diff(rollout.trajectories["robot/ee"], axis=0), axis=1) / rollout.dt


# --- belief and assistance ----------------------------------------------------------------


@pytest.mark.parametrize(("goal0", "goal1"), [(LOW, HIGH), (HIGH, LOW)], ids=["goal0-low", "goal0-high"])
def test_belief_moves_toward_the_goal_the_user_heads_for(goal0, goal1):
    # Swapping the goals swaps nothing in the belief's index: it follows the user, not the layout.
    _, rollout = run("teleop", theta_of(goal0, goal1))
    belief = beliefs(rollout)
    assert belief is not None and belief.shape[1] == 2
    np.testing.assert_allclose(belief.sum(axis=1), 1.0, atol=1e-9)
    assert belief[0] == pytest.approx([0.5, 0.5], abs=0.01)  # uniform prior, one small step
    # A noiseless user heading straight for goal0 only ever adds evidence for goal0 ...
    assert np.all(np.diff(belief[:, 0]) >= -1e-9)
    assert belief[len(belief) // 2, 0] > 0.55
    # ... until the belief reaches its cap (max_probability 0.99), never beyond.
    assert belief[-1, 0] == pytest.approx(0.99, abs=1e-6)
    assert belief.max() <= 0.99 + 1e-9


@pytest.mark.parametrize(("goal0", "goal1"), [(LOW, HIGH), (HIGH, LOW)], ids=["goal0-low", "goal0-high"])
def test_robot_reaches_the_true_goal_well_inside_the_time_limit(goal0, goal1):
    evaluation, rollout = run("teleop", theta_of(goal0, goal1))
    assert evaluation.objective == evaluation.metrics["completion_time"]
    assert evaluation.objective < 6.0  # the limit is 10 s; the user alone would need ~5 s at 0.05 m/s
    assert not evaluation.failure
    assert rollout.events[-1][1] == "reached goal0"
    end = rollout.trajectories["robot/ee"][-1]
    assert np.linalg.norm(end - [*goal0, GOAL_Z]) < 0.01  # the reference's 1 cm tolerance
    assert np.linalg.norm(end[:2] - np.array(goal1)) > 0.2


def test_a_distractor_on_the_users_path_slows_the_robot_down():
    """The paper's failure mode: the user drives through goal1 on the way to goal0, the robot infers
    goal1 and keeps pulling toward it; with the same goal1 off the path the episode is quick."""
    goal0 = (0.66, 0.05)  # straight ahead of the start (0.41, 0.05)
    on_path, _ = run("teleop", theta_of(goal0, (0.55, 0.05)))
    off_path, _ = run("teleop", theta_of(goal0, (0.55, 0.16)))
    assert off_path.objective < 6.0
    assert on_path.objective > off_path.objective + 2.0
    # The robot's belief is captured by the distractor, which the sideways one never manages.
    assert on_path.metrics["max_wrong_goal_probability"] > 0.9
    assert off_path.metrics["max_wrong_goal_probability"] < 0.6


def test_the_same_theta_gives_the_same_evaluation_twice():
    theta = theta_of((0.63, -0.02), (0.57, 0.12), (0.02, -0.03, 0.01, 0.04, -0.02))
    d = domain("teleop")
    (a, ra), (b, rb) = (evaluate_with_rollout(d, np.array(theta), seed=0) for _ in range(2))
    assert a.ok and b.ok, (a.message, b.message)
    assert a.objective == b.objective
    np.testing.assert_array_equal(a.measures, b.measures)
    assert a.metrics == b.metrics
    np.testing.assert_array_equal(a.theta_repaired, b.theta_repaired)
    assert a.failure == b.failure
    np.testing.assert_array_equal(ra.trajectories["robot/ee"], rb.trajectories["robot/ee"])
    np.testing.assert_array_equal(beliefs(ra), beliefs(rb))
    assert ra.events == rb.events


# --- policy blending ----------------------------------------------------------------------


def test_blending_reaches_the_goal_and_follows_the_user_until_confident():
    goal0, goal1 = LOW, HIGH
    evaluation, rollout = run("teleop_blend", theta_of(goal0, goal1))
    assert evaluation.objective < 20.0 and not evaluation.failure  # its time limit is 20 s
    assert rollout.events[-1][1] == "reached goal0"
    assert np.linalg.norm(rollout.trajectories["robot/ee"][-1] - [*goal0, GOAL_Z]) < 0.01

    # While the top-two belief gap is at most the threshold (0.4), the arm moves exactly as the
    # user commands: no faster than the user's 0.05 m/s joystick speed ...
    def low_confidence(belief):
        top = np.sort(belief, axis=1)
        return top[:, -1] - top[:, -2] <= 0.4

    quiet = low_confidence(beliefs(rollout))
    assert quiet.sum() > 40 and not quiet[-1]
    assert ee_speeds(rollout)[quiet].max() <= 0.05 * 1.02
    # ... whereas hindsight assistance adds its own twist at the same confidence.
    _, assisted = run("teleop", theta_of(goal0, goal1))
    assert ee_speeds(assisted)[low_confidence(beliefs(assisted))].max() > 0.06


# --- misbehaving robot plugins ------------------------------------------------------------

PLUGIN = """
from typing import ClassVar

import numpy as np

from hritest_plugins.actions import RobotAction


class Robot:
    kind: ClassVar[str] = "robot"

    def __init__(self, *, params, scenario, rng):
        if {fault!r} == "init":
            raise RuntimeError("robot could not start")
        self.ticks = 0

    def act(self, observation):
        self.ticks += 1
        if {fault!r} == "raise" and self.ticks == 5:
            raise RuntimeError("robot exploded")
        twist = np.zeros(6)
        if {fault!r} == "nan" and self.ticks == 5:
            twist[0] = np.nan
        return RobotAction(twist=twist + observation["user_twist"])
"""


@pytest.mark.parametrize(
    ("fault", "words"),
    [
        ("raise", "robot plugin Robot raised RuntimeError: robot exploded"),
        ("init", "robot plugin Robot raised RuntimeError: robot could not start"),
        ("nan", "robot plugin Robot returned a non-finite value"),
    ],
    ids=["raises-in-act", "raises-in-init", "nan-twist"],
)
def test_a_robot_plugin_that_raises_or_returns_nan_gives_plugin_error(tmp_path, fault, words):
    (tmp_path / "robot.py").write_text(PLUGIN.format(fault=fault))
    text = (SPECS / "teleop.yaml").read_text()
    assert text.count("  policy: hindsight\n") == 1
    spec = tmp_path / "teleop.yaml"
    spec.write_text(text.replace("  policy: hindsight\n", "  policy: robot.py:Robot\n"))
    d = compile_spec(load_spec(spec))
    assert d.robot_cls.__name__ == "Robot"

    evaluation, rollout = evaluate_with_rollout(d, np.array(theta_of(LOW, HIGH)), seed=0)  # never raises
    assert evaluation.status == "plugin_error"
    assert words in evaluation.message
    assert rollout is None
    assert not evaluation.failure and np.isnan(evaluation.objective)


# --- the recorded episode -----------------------------------------------------------------


def test_the_recorded_rollout_ends_at_the_reported_completion_time():
    evaluation, rollout = run("teleop", theta_of(LOW, HIGH))
    completion = evaluation.metrics["completion_time"]
    assert rollout.time[-1] == pytest.approx(completion, abs=1e-9)
    assert rollout.events[-1][0] == pytest.approx(completion, abs=1e-9)
    n = len(rollout.time)
    assert rollout.trajectories["robot/ee"].shape == (n, 3) and len(rollout.scene.qpos) == n
    assert len(beliefs(rollout)) == n - 1  # the robot acts on every tick but the one at the goal
    np.testing.assert_allclose(np.diff(rollout.time), rollout.dt)
    # The end effector starts where the user's path does.
    assert rollout.trajectories["robot/ee"][0][:2] == pytest.approx([0.41, 0.05], abs=0.01)


def test_an_episode_that_never_reaches_the_goal_is_recorded_to_the_time_limit():
    evaluation, rollout = run("teleop", theta_of((0.66, 0.05), (0.55, 0.05)))
    assert evaluation.objective == pytest.approx(10.0) and evaluation.failure  # failure: objective >= 10
    assert rollout.time[-1] == pytest.approx(10.0, abs=1e-9)
    assert not any("reached" in text for _, text in rollout.events)
    assert np.linalg.norm(rollout.trajectories["robot/ee"][-1][:2] - [0.66, 0.05]) >= 0.01
