"""Twist -> joint velocities: the reference's bounded least squares, scaling and limit test."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from hritest.sim.control import _bvls, twist_to_joint_velocity

SPEEDS = np.full(6, 0.8)
FREE = {"lower": np.full(6, -np.inf), "upper": np.full(6, np.inf), "velocity_limits": SPEEDS}


def jacobian(seed: int = 0) -> np.ndarray:
    return np.eye(6) + 0.3 * np.random.default_rng(seed).normal(size=(6, 6))


def test_a_reachable_twist_is_met_exactly():
    jac, twist = jacobian(), np.array([0.05, -0.02, 0.01, 0.0, 0.1, 0.0])
    qdot, limit_reached = twist_to_joint_velocity(jac, twist, np.zeros(6), **FREE)
    np.testing.assert_allclose(jac @ qdot, twist, atol=1e-12)
    assert not limit_reached


def test_a_fast_twist_is_bounded_then_scaled_to_95_percent():
    jac, twist = jacobian(), np.array([2.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    qdot, _ = twist_to_joint_velocity(jac, twist, np.zeros(6), **FREE)
    assert np.max(np.abs(qdot) / SPEEDS) == pytest.approx(0.95)
    # It is the bounded optimum, scaled: the direction matches lsq_linear's solution.
    best = lsq_linear(jac, twist, bounds=(-SPEEDS, SPEEDS)).x
    np.testing.assert_allclose(qdot, best * 0.95 / np.max(np.abs(best) / SPEEDS), atol=1e-6)


def test_no_motion_further_into_a_limit_within_the_margin():
    jac = np.eye(6)
    lower, upper = np.full(6, -1.0), np.full(6, 1.0)
    q = np.array([0.98, -0.98, 0.5, 0.0, 0.0, 0.0])  # joint 0 near upper, joint 1 near lower
    twist = np.full(6, 0.1)
    qdot, _ = twist_to_joint_velocity(jac, twist, q, lower=lower, upper=upper, velocity_limits=SPEEDS)
    assert qdot[0] == 0.0  # would go further up: blocked
    assert qdot[1] == pytest.approx(0.1)  # moves away from its lower limit: allowed
    np.testing.assert_allclose(qdot[2:], 0.1)


def test_one_tick_never_crosses_a_limit_even_without_a_margin():
    q, upper = np.zeros(6), np.full(6, 0.01)
    qdot, _ = twist_to_joint_velocity(
        np.eye(6),
        np.full(6, 0.5),
        q,
        lower=-upper,
        upper=upper,
        velocity_limits=SPEEDS,
        margin=0.0,
    )
    assert np.all(q + qdot * 0.025 <= upper + 1e-15)


def test_a_joint_with_no_room_either_way_is_pinned():
    lower, upper = np.full(6, -np.inf), np.full(6, np.inf)
    lower[0], upper[0] = -0.01, 0.01  # narrower than twice the margin
    qdot, _ = twist_to_joint_velocity(
        np.eye(6), np.full(6, 0.1), np.zeros(6), lower=lower, upper=upper, velocity_limits=SPEEDS
    )
    assert qdot[0] == 0.0
    np.testing.assert_allclose(qdot[1:], 0.1)


@pytest.mark.parametrize(
    ("twist", "expected"),
    [
        # Ratios (0, 1, 1) have norm 1.41: as in the reference, one blocked axis of three is not
        # enough to fire the test.
        ([0.1, 0.1, 0.1, 0, 0, 0], False),
        ([0.1, 0.0, 0.0, 0, 0, 0], True),  # x is blocked: ratio 0 on the only asked component
        ([0.0, 0.1, 0.0, 0, 0, 0], False),  # y is free; the zero x and z are left out
        ([0.0, 0.0, 0.0, 0, 0, 0.2], False),  # no translation asked: nothing fell short
    ],
)
def test_limit_reached_is_the_translation_ratio_test(twist, expected):
    # Joint 0 alone moves the EE along x and sits at its upper limit.
    lower, upper = np.full(6, -np.inf), np.full(6, np.inf)
    upper[0] = 0.0
    _, limit_reached = twist_to_joint_velocity(
        np.eye(6),
        np.array(twist, dtype=float),
        np.zeros(6),
        lower=lower,
        upper=upper,
        velocity_limits=SPEEDS,
    )
    assert limit_reached is expected


def test_a_singular_jacobian_still_gives_finite_velocities():
    jac = jacobian()
    jac[:, 5] = jac[:, 4]  # two joints doing the same thing
    qdot, _ = twist_to_joint_velocity(jac, np.full(6, 0.05), np.zeros(6), **FREE)
    assert np.all(np.isfinite(qdot)) and np.all(np.abs(qdot) <= 0.95 * SPEEDS + 1e-12)


def test_the_bounded_solver_is_scipys_bvls_to_the_bit():
    # _bvls re-implements lsq_linear(method="bvls") without its per-call overhead; same steps.
    rng = np.random.default_rng(11)
    for _ in range(300):
        n = int(rng.integers(1, 7))
        a, b = rng.normal(size=(6, n)), rng.normal(size=6) * rng.uniform(0.1, 5.0)
        lb, ub = -rng.uniform(0.05, 1.0, n), rng.uniform(0.05, 1.0, n)
        np.testing.assert_array_equal(_bvls(a, b, lb, ub), lsq_linear(a, b, bounds=(lb, ub), method="bvls").x)
