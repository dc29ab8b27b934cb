"""Hindsight-optimisation shared autonomy: Huber values, actions, belief, assisted twists."""

from __future__ import annotations

import numpy as np
import pytest
from hritest_plugins import blending, hindsight, huber, poses
from hritest_plugins import teleop_human as th
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

C = huber.DEFAULT_CONSTANTS
Z = 0.96  # goal height


def pose_at(xyz, rotation=poses.GOAL_ROTATION) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = xyz
    return pose


def value_at_distance(d: float) -> float:
    """V of a target straight ahead (+x) at distance d, orientation matched (V_r = 0)."""
    target = pose_at([0.6, 0.0, Z])
    return float(huber.target_value(pose_at([0.6 - d, 0.0, Z]), target))


# --- Huber value --------------------------------------------------------------------------


def test_value_matches_the_reference_formula_on_both_sides_of_delta():
    a, delta, c = C.translation_linear, C.translation_delta, C.translation_constant
    assert value_at_distance(0.03) == pytest.approx(a / (2 * delta) * 0.03**2 + c * 0.03)
    assert value_at_distance(0.3) == pytest.approx((a + c) * 0.3 - a * delta / 2)


def test_value_is_continuous_and_differentiable_at_delta():
    delta, eps = C.translation_delta, 1e-8
    below, at, above = (value_at_distance(delta + s) for s in (-eps, 0.0, eps))
    # no jump: the change across delta is only the slope (a_t + c_t = 2.45) times the step
    assert above - below == pytest.approx(2.45 * 2 * eps, abs=1e-10)
    slope_below = (at - value_at_distance(delta - 1e-5)) / 1e-5
    slope_above = (value_at_distance(delta + 1e-5) - at) / 1e-5
    assert slope_below == pytest.approx(slope_above, rel=1e-3)
    assert slope_above == pytest.approx(C.translation_linear + C.translation_constant, rel=1e-3)


def test_rotation_value_is_zero_only_for_the_matching_target():
    targets = poses.target_poses([0.6, 0.0, Z])
    pose = pose_at([0.6, 0.0, Z])
    v_same, v_flipped = huber.target_value(pose, targets)
    assert v_same == pytest.approx(0.0, abs=1e-12)
    a, delta, c = C.rotation_linear, C.rotation_delta, C.rotation_constant
    assert v_flipped == pytest.approx(C.rotation_multiplier * ((a + c) * np.pi - a * delta / 2))


def test_q_value_is_step_cost_plus_value_after_the_action():
    target = pose_at([0.6, 0.0, Z])
    pose = pose_at([0.3, 0.0, Z])  # 0.3 m away: linear regime, slope 2.45
    v = huber.target_value(pose, target)
    rotation_cost = C.action_apply_time * C.rotation_multiplier * C.rotation_constant
    q_still = huber.target_q_value(pose, np.zeros(6), target)
    assert q_still - v == pytest.approx(C.action_apply_time * 2.45 + rotation_cost)
    q_toward = huber.target_q_value(pose, [0.05, 0, 0, 0, 0, 0], target)
    assert q_toward - v == pytest.approx(C.action_apply_time * 2.45 * (1 - 0.05) + rotation_cost)
    assert huber.target_q_value(pose, [-0.05, 0, 0, 0, 0, 0], target) > q_still > q_toward


# --- apply_twist --------------------------------------------------------------------------


def test_zero_twist_is_identity():
    pose = pose_at([0.3, -0.2, 0.9])
    np.testing.assert_allclose(poses.apply_twist(pose, np.zeros(6), 0.1), pose, atol=1e-15)


def test_pure_translation_moves_by_velocity_times_duration():
    pose = pose_at([0.3, -0.2, 0.9])
    moved = poses.apply_twist(pose, [0.1, -0.2, 0.05, 0, 0, 0], 0.5)
    np.testing.assert_allclose(moved[:3, 3], [0.35, -0.3, 0.925])
    np.testing.assert_allclose(moved[:3, :3], pose[:3, :3])


def test_rotation_is_world_frame_and_composes():
    pose = pose_at([0.3, -0.2, 0.9])
    quarter = poses.apply_twist(pose, [0, 0, 0, 0, 0, np.pi / 2], 1.0)
    rz90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(quarter[:3, :3], rz90 @ poses.GOAL_ROTATION, atol=1e-12)
    twice = poses.apply_twist(poses.apply_twist(pose, [0, 0, 0, 0.3, 0, 0], 0.5), [0, 0, 0, 0.3, 0, 0], 0.5)
    once = poses.apply_twist(pose, [0, 0, 0, 0.3, 0, 0], 1.0)
    np.testing.assert_allclose(twice, once, atol=1e-12)
    # the pose after yawing by pi is exactly the goal's second target
    flipped = poses.apply_twist(pose_at([0.6, 0, Z]), [0, 0, 0, 0, 0, np.pi], 1.0)
    np.testing.assert_allclose(flipped, poses.target_poses([0.6, 0, Z])[1], atol=1e-12)


# --- per-target action --------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(
    st.tuples(st.floats(-0.4, 0.4), st.floats(-0.4, 0.4), st.floats(-0.1, 0.1)).filter(
        lambda p: np.linalg.norm(p) > 0.025 and abs(np.linalg.norm(p) - 0.07) > 1e-3
    )
)
def test_translation_action_is_minus_gradient_of_value_over_40(offset):
    target = pose_at([0.6, 0.0, Z])
    pose = pose_at(np.array([0.6, 0.0, Z]) + offset)
    eps = 1e-6
    grad = np.array(
        [
            (
                huber.target_value(pose_at(pose[:3, 3] + e), target)
                - huber.target_value(pose_at(pose[:3, 3] - e), target)
            )
            / (2 * eps)
            for e in np.eye(3) * eps
        ]
    )
    action = huber.target_action(pose, target)
    np.testing.assert_allclose(action[:3], -grad / C.robot_translation_cost, atol=1e-7)
    toward = (target[:3, 3] - pose[:3, 3]) / np.linalg.norm(offset)
    assert action[:3] @ toward == pytest.approx(np.linalg.norm(action[:3]))


def test_translation_speed_is_capped_and_slows_down_near_the_target():
    target = pose_at([0.6, 0.0, Z])
    far = huber.target_action(pose_at([0.0, 0.5, Z]), target)
    assert np.linalg.norm(far[:3]) == pytest.approx(0.06125)
    assert C.max_translation_speed == pytest.approx(0.06125)
    speeds = [np.linalg.norm(huber.target_action(pose_at([0.6 - d, 0, Z]), target)[:3]) for d in (0.005, 0.01, 0.019)]
    assert speeds[0] < speeds[1] < speeds[2] < 0.06125
    np.testing.assert_array_equal(huber.target_action(target, target), np.zeros(6))


def test_rotation_action_turns_toward_the_target_the_short_way():
    target = pose_at([0.6, 0.0, Z])
    for axis in np.eye(3):
        for angle in (0.1, 1.0, 3.0):
            tilted = poses.apply_twist(target, np.r_[0, 0, 0, axis * angle], 1.0)
            omega = huber.target_action(tilted, target)[3:]
            np.testing.assert_allclose(omega / np.linalg.norm(omega), -axis, atol=1e-9)
            stepped = poses.apply_twist(tilted, np.r_[0, 0, 0, omega], 0.025)
            assert huber.target_value(stepped, target) < huber.target_value(tilted, target)


# --- goal values and belief ---------------------------------------------------------------


def two_goals(y1: float = 0.12) -> np.ndarray:
    return np.stack([poses.target_poses([0.6, 0.0, Z]), poses.target_poses([0.6, y1, Z])])


def test_goal_value_is_that_of_the_closer_target():
    goals = two_goals()
    pose = poses.apply_twist(pose_at([0.41, 0.05, Z]), [0, 0, 0, 0, 0, 2.9], 1.0)
    values, q_values, best = huber.goal_values(pose, np.zeros(6), goals)
    np.testing.assert_array_equal(best, [1, 1])  # yawed almost pi: the flipped target
    np.testing.assert_allclose(values, huber.target_value(pose, goals).min(axis=1))
    assert np.all(q_values > values)  # standing still is never optimal


def simulate_approach(goals: np.ndarray, aim_xy, ticks: int = 80):
    """The teleoperation user drives the EE straight at ``aim_xy``; returns the beliefs."""
    pose = pose_at([0.41, 0.05, Z])
    log_b = hindsight.uniform_log_belief(len(goals))
    beliefs = []
    for _ in range(ticks):
        twist = th.user_twist(th.user_velocity(pose[:3, 3], aim_xy))
        values, q_values, _ = huber.goal_values(pose, twist, goals)
        log_b = hindsight.update_belief(log_b, values, q_values)
        beliefs.append(np.exp(log_b))
        pose = poses.apply_twist(pose, twist, 0.025)
    return np.array(beliefs)


def test_belief_moves_toward_the_goal_the_user_heads_for():
    beliefs = simulate_approach(two_goals(), aim_xy=[0.6, 0.0])
    np.testing.assert_allclose(beliefs.sum(axis=1), 1.0)
    assert np.all(np.diff(beliefs[:, 0]) > 0)
    assert beliefs[-1, 0] > 0.55
    assert beliefs.max() <= 0.99 + 1e-12


def test_belief_stays_uniform_between_symmetric_goals():
    goals = np.stack([poses.target_poses([0.6, 0.05 - 0.06, Z]), poses.target_poses([0.6, 0.05 + 0.06, Z])])
    beliefs = simulate_approach(goals, aim_xy=[0.6, 0.05])
    np.testing.assert_allclose(beliefs, 0.5, atol=1e-12)


def test_belief_is_capped_at_099_with_the_excess_spread_evenly():
    log_b = hindsight.update_belief(np.log([0.5, 0.3, 0.2]), np.zeros(3), np.array([0.0, 20.0, 25.0]))
    b = np.exp(log_b)
    assert b.sum() == pytest.approx(1.0)
    assert b[0] == pytest.approx(0.99)
    # before the cap b ~ [1, 1.2e-9, 8.3e-12]; each other goal gets half the excess 0.01
    np.testing.assert_allclose(b[1:], 0.005, rtol=1e-6)
    assert b[1] > b[2]


def test_belief_update_is_plain_bayes_below_the_cap():
    log_b = hindsight.update_belief(np.log([0.5, 0.5]), np.array([1.0, 1.0]), np.array([1.1, 1.3]))
    expected = np.array([np.exp(-0.1), np.exp(-0.3)])
    np.testing.assert_allclose(np.exp(log_b), expected / expected.sum())


# --- assisted twists ----------------------------------------------------------------------

ACTIONS = np.array([[1.0, 0, 0, 0, 0, 0], [0, 1.0, 0, 0, 0, 0], [0, 0, 1.0, 0, 0, 0]])
USER = np.array([0.01, 0.02, 0, 0, 0, 0])


def test_teleop_twist_is_belief_weighted_mean_plus_user():
    twist = hindsight.assisted_twist_teleop([0.5, 0.3, 0.2], ACTIONS, USER)
    np.testing.assert_allclose(twist, [0.51, 0.32, 0.2, 0, 0, 0])


@pytest.mark.parametrize(
    ("values", "visited", "expected"),
    [
        ([0.3, 0.1, 0.2], [], [1, 2, 1]),  # nearest goal other than the human's
        ([0.3, 0.1, 0.2], [1], [2, 2, 0]),  # 1 done: avoid it
        ([0.3, 0.1, 0.2], [1, 2], [0, 0, 0]),  # only 0 left: share it if the human wants it
        ([0.3, 0.1, 0.2], [0, 1, 2], [-1, -1, -1]),  # all done
        ([0.2, 0.2, 0.1], [2], [1, 0, 0]),  # tie between 0 and 1 goes to the lower index
    ],
)
def test_feasible_goal_mapping(values, visited, expected):
    np.testing.assert_array_equal(hindsight.feasible_goal_mapping(values, visited), expected)


def test_collab_twist_follows_the_mapping_and_ignores_infeasible_goals():
    twist = hindsight.assisted_twist_collab([0.6, 0.3, 0.1], ACTIONS, [2, 2, 0])
    np.testing.assert_allclose(twist, [0.1, 0, 0.9, 0, 0, 0])
    none = hindsight.assisted_twist_collab([0.6, 0.3, 0.1], ACTIONS, [-1, 2, -1])
    np.testing.assert_allclose(none, [0, 0, 0.3, 0, 0, 0])


def test_blending_follows_the_user_until_confident():
    unsure = blending.blend_twist([0.5, 0.3, 0.2], ACTIONS, USER)
    np.testing.assert_array_equal(unsure, USER)
    sure = blending.blend_twist([0.1, 0.8, 0.1], ACTIONS, USER)
    np.testing.assert_allclose(sure, ACTIONS[1] + USER)


def test_timid_blending_mixes_xy_by_confidence():
    conf = 0.6  # top-two gap: alpha = 1.5 * (0.6 - 0.4) = 0.3
    twist = blending.blend_twist([0.1, 0.75, 0.15], ACTIONS, USER, mode="timid")
    assert pytest.approx(conf) == 0.75 - 0.15
    assisted = ACTIONS[1] + USER
    np.testing.assert_allclose(twist[:2], 0.3 * assisted[:2] + 0.7 * USER[:2])
    capped = blending.blend_twist([0.0, 0.99, 0.01], ACTIONS, USER, mode="timid")
    np.testing.assert_allclose(capped[:2], 0.6 * assisted[:2] + 0.4 * USER[:2])
    with pytest.raises(ValueError, match="timid"):
        blending.blend_twist([1.0], ACTIONS[:1], USER, mode="bold")


# --- the prepared per-tick path -----------------------------------------------------------


def test_rotation_angle_matches_scipy_at_every_angle_including_half_turns():
    rng = np.random.default_rng(4)
    half_turns = Rotation.from_rotvec(np.pi * Rotation.random(20, random_state=rng).apply([1.0, 0.0, 0.0]))
    target = pose_at([0.6, 0.0, Z])
    for turn in [*Rotation.random(200, random_state=rng), *half_turns]:
        _, angle = poses.pose_distances(pose_at([0.5, 0.1, Z], turn.as_matrix() @ poses.GOAL_ROTATION), target)
        assert angle == pytest.approx(turn.magnitude(), abs=1e-12)


@pytest.mark.parametrize("twist", [[0.03, -0.01, 0.0, 0.0, 0.0, 0.0], [0.03, -0.01, 0.01, 0.2, -0.1, 0.3]])
def test_lookahead_agrees_with_the_per_target_functions(twist):
    goals = two_goals()
    pose = poses.apply_twist(pose_at([0.45, 0.02, Z]), [0, 0, 0, 0.1, 0.2, 0.3], 1.0)
    look = huber.lookahead(pose, twist, poses.prepare_targets(goals))
    after = poses.apply_twist(pose, twist, C.action_apply_time)
    np.testing.assert_allclose(np.reshape(look.values, (2, 2)), huber.target_value(pose, goals), atol=1e-12)
    np.testing.assert_allclose(np.reshape(look.q_values, (2, 2)), huber.target_q_value(pose, twist, goals), atol=1e-12)
    np.testing.assert_allclose(np.reshape(look.values_after, (2, 2)), huber.target_value(after, goals), atol=1e-12)
    best = np.reshape(look.values_after, (2, 2)).argmin(axis=1)
    expected = huber.target_action(after, goals[np.arange(2), best])
    np.testing.assert_allclose(huber.goal_actions(look.after, look.values_after, 2), expected, atol=1e-12)


@pytest.mark.parametrize("twist", [[0.03, -0.01, 0.0, 0.0, 0.0, 0.0], [0.03, -0.01, 0.01, 0.2, -0.1, 0.3]])
def test_teleop_step_is_belief_update_and_actions_after_the_twist(twist):
    goals = np.stack([*two_goals(), poses.target_poses([0.5, -0.1, Z])])
    targets = poses.prepare_targets(goals)
    pose = poses.apply_twist(pose_at([0.45, 0.02, Z]), [0, 0, 0, 0.1, 0.2, 0.3], 1.0)
    log_b = np.log([0.5, 0.3, 0.2])
    look = huber.lookahead(pose, twist, targets)
    values, q_values, _ = look.per_goal()
    new_log_b, actions = hindsight.teleop_step(pose, np.asarray(twist), targets, log_b)
    np.testing.assert_array_equal(new_log_b, hindsight.update_belief(log_b, values, q_values))
    np.testing.assert_array_equal(actions, huber.goal_actions(look.after, look.values_after, 2))


def test_within_needs_both_distance_and_angle():
    targets = poses.prepare_targets(poses.target_poses([0.6, 0.0, Z]))
    near = pose_at([0.6, 0.005, Z])
    assert poses.within(near, targets, distance=0.01, angle=0.1)
    assert not poses.within(near, targets, distance=0.004, angle=0.1)
    tilted = poses.apply_twist(near, [0, 0, 0, 0.3, 0, 0], 1.0)  # 0.3 rad from both targets
    assert not poses.within(tilted, targets, distance=0.01, angle=0.1)
    assert poses.within(tilted, targets, distance=0.01, angle=0.31)
