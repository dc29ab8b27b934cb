"""The simulated teleoperation user: waypoints, the UserBot velocity rule, the advance rule."""

from __future__ import annotations

import numpy as np
import pytest
from hritest_plugins import poses
from hritest_plugins import teleop_human as th
from hypothesis import given, settings
from hypothesis import strategies as st

START = np.array([0.41, 0.05])
GOAL = np.array([0.6, 0.1])
NOISE = np.array([0.05, -0.05, 0.02, 0.0, -0.01])


def test_waypoints_are_a_line_with_noise_on_interior_y_only():
    points = th.waypoints(START, GOAL, NOISE)
    clean = th.waypoints(START, GOAL, np.zeros(5))
    assert points.shape == (7, 2)
    np.testing.assert_array_equal(points[0], START)
    np.testing.assert_array_equal(points[-1], GOAL)
    np.testing.assert_allclose(np.diff(clean[:, 0]), (GOAL[0] - START[0]) / 6)
    np.testing.assert_allclose(clean[:, 1], np.linspace(START[1], GOAL[1], 7))
    np.testing.assert_array_equal(points[:, 0], clean[:, 0])
    np.testing.assert_allclose(points[1:-1, 1] - clean[1:-1, 1], NOISE)


def test_waypoints_reject_the_wrong_number_of_offsets():
    with pytest.raises(ValueError, match=r"\(5,\)"):
        th.waypoints(START, GOAL, np.zeros(7))


@settings(max_examples=100, deadline=None)
@given(st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)))
def test_user_velocity_is_proportional_then_clipped(delta):
    current = np.array([0.0, 0.0, 0.9])  # at the origin so target - current is exact
    v = th.user_velocity(current, current + np.array(delta))
    raw = 10 * np.array(delta[:2])
    assert v.shape == (2,)
    assert np.linalg.norm(v) <= 0.25 + 1e-12
    if np.linalg.norm(raw) <= 0.25:
        np.testing.assert_allclose(v, raw)
    else:  # same direction, norm exactly 0.25
        np.testing.assert_allclose(v, raw / np.linalg.norm(raw) * 0.25)


def test_user_velocity_ignores_z():
    v = th.user_velocity([0.5, 0.0, 0.0], [0.51, 0.0, 5.0])
    np.testing.assert_allclose(v, [0.1, 0.0])


def test_user_twist_is_a_fifth_of_the_command_in_xy():
    np.testing.assert_allclose(th.user_twist([0.25, -0.1]), [0.05, -0.02, 0, 0, 0, 0])


def test_waypoint_advances_when_passed_in_x_or_reached():
    path = th.waypoints(START, GOAL, np.zeros(5))
    far = th.user_velocity([0.3, 0.0], path[2])
    assert th.next_waypoint_index(2, path, [0.3, 0.0], far) == 2
    assert th.next_waypoint_index(2, path, [path[2, 0] + 1e-3, 0.5], far) == 3  # passed in x
    near = th.user_velocity(path[2] - [1e-4, 0], path[2])
    assert th.next_waypoint_index(2, path, path[2] - [1e-4, 0], near) == 3  # there
    assert th.next_waypoint_index(6, path, [1.0, 0.0], near) == 6  # never past the goal


def test_simulated_user_alone_reaches_the_goal_through_the_waypoints():
    path = th.waypoints(START, GOAL, NOISE)
    pose = np.eye(4)
    pose[:3, 3] = [*START, 0.9]
    index, max_dev = 0, 0.0
    # alone, the user closes in on every waypoint (the x-pass shortcut only fires when the
    # robot's assistance carries the EE ahead), so it needs more than the 10 s episode
    for _ in range(1200):  # 30 s
        v = th.user_velocity(pose[:3, 3], path[index])
        index = th.next_waypoint_index(index, path, pose[:3, 3], v)
        pose = poses.apply_twist(pose, th.user_twist(v), 0.025)
        max_dev = max(max_dev, abs(pose[1, 3] - np.interp(pose[0, 3], path[:, 0], path[:, 1])))
    assert index == 6
    assert np.linalg.norm(pose[:2, 3] - GOAL) < 0.01
    assert max_dev < 0.03  # it follows the noisy path, not the straight line


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 6), st.floats(0.3, 0.7), st.floats(-0.1, 0.2))
def test_user_step_is_velocity_advance_and_twist_in_one_call(index, x, y):
    path = th.waypoints(START, GOAL, NOISE)
    ee = np.array([x, y, 0.96])
    command = th.user_velocity(ee, path[index])
    expected = th.next_waypoint_index(index, path, ee, command), th.user_twist(command)
    got = th.user_step(index, path, ee, gain=10.0, max_speed=0.25, weight=0.2)
    assert got[0] == expected[0]
    np.testing.assert_array_equal(got[1], expected[1])
