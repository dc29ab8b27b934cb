"""The nearest passing scenario to a failure: it passes, it is nearer than the nominal scenario,
and the parameters it changes are the ones the failure needs."""

from __future__ import annotations

import numpy as np
import pytest

from hritest.counterfactual import CounterfactualError, counterfactual
from hritest.domain import compile_spec
from hritest.evaluate import evaluate
from hritest.spec import load_spec

G0X = "{name: g0x, bind: task.g0x, bounds: [0.52, 0.68]"
G1X = "{name: g1x, bind: task.g1x, bounds: [0.52, 0.68]"


@pytest.fixture
def domain(toy_spec):
    """The toy domain with a passing nominal scenario: goals 0.16 m apart, no noise."""
    text = (
        toy_spec().read_text().replace(G0X + "}", G0X + ", nominal: 0.52}").replace(G1X + "}", G1X + ", nominal: 0.68}")
    )
    return compile_spec(load_spec(toy_spec(text=text)))


def normalised(domain, a, b) -> float:
    return float(np.linalg.norm((np.asarray(a) - b) / (domain.space.upper - domain.space.lower)))


def test_the_counterfactual_passes_and_is_nearer_than_nominal(domain):
    failing = np.array([0.6, 0.05, 0.61, 0.06, 0.0, 0.0, 0.0])  # close goals, no noise: completion 9.2
    assert evaluate(domain, failing, seed=0).failure
    found = counterfactual(domain, failing, seed=0)
    again = evaluate(domain, found.theta, seed=0)
    assert again.ok and not again.failure and not found.passing.failure
    assert found.distance == pytest.approx(normalised(domain, found.theta, failing))
    assert found.distance < normalised(domain, domain.nominal, failing)
    assert set(found.changed) <= {"g0x", "g0y", "g1x", "g1y"}  # moving the goals apart fixes it; noise cannot
    assert found.evaluations <= 60


def test_a_scenario_that_passes_has_no_counterfactual(domain):
    with pytest.raises(CounterfactualError, match="not a failure"):
        counterfactual(domain, domain.nominal, seed=0)


def test_the_budget_bounds_the_search(domain):
    failing = np.array([0.6, 0.05, 0.61, 0.06, 0.0, 0.0, 0.0])
    assert counterfactual(domain, failing, seed=0, budget=2).evaluations == 2  # the failure, one move
    with pytest.raises(CounterfactualError, match="no passing scenario found in 1 simulations"):
        counterfactual(domain, failing, seed=0, budget=1)
