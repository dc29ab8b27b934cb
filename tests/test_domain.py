"""Compiling a spec fixes theta's layout; binding theta gives a concrete scenario."""

from __future__ import annotations

import numpy as np
import pytest

from hritest.domain import compile_spec
from hritest.spec import load_spec


@pytest.fixture
def domain(toy_spec):
    return compile_spec(load_spec(toy_spec()))


def test_layout_follows_the_spec_order(domain):
    space = domain.space
    assert space.labels == ["g0x", "g0y", "g1x", "g1y", "noise[0]", "noise[1]", "noise[2]"]
    np.testing.assert_array_equal(space.lower, [0.52, -0.08, 0.52, -0.08, -0.05, -0.05, -0.05])
    np.testing.assert_array_equal(space.upper, [0.68, 0.18, 0.68, 0.18, 0.05, 0.05, 0.05])


def test_bind_moves_objects_and_sets_model_parameters(domain):
    theta = np.array([0.55, 0.1, 0.66, -0.02, 0.01, -0.02, 0.03])
    scenario = domain.space.bind(theta)
    np.testing.assert_allclose(scenario.objects["goal0"], [0.55, 0.1, 0.96])
    np.testing.assert_allclose(scenario.objects["goal1"], [0.66, -0.02, 0.96])
    np.testing.assert_allclose(scenario.human["noise"], [0.01, -0.02, 0.03])
    assert scenario.human["speed"] == 1.0  # unbound: the plugin's default
    assert scenario.task["scale"] == 1.0 and scenario.task["fault"] == "none"
    assert scenario.values["g1y"] == -0.02
    # Binding does not alias theta or the nominal positions.
    theta[0] = 0.0
    assert scenario.objects["goal0"][0] == 0.55
    assert domain.space.bind(theta).objects["goal1"][0] == 0.66
    assert domain.space.nominal_objects["goal0"][0] == 0.6


def test_bind_rejects_a_theta_of_the_wrong_length(domain):
    with pytest.raises(ValueError, match="7 components"):
        domain.space.bind(np.zeros(6))


def test_expressions_are_compiled(domain):
    assert domain.objective.evaluate({"completion_time": 3.0}) == 3.0
    variation = domain.measures[1].expression.evaluate({"noise": np.array([0.0, 0.03, 0.04])})
    assert variation == pytest.approx(0.05)
    assert domain.failure.evaluate({"objective": 9.0}) is True
