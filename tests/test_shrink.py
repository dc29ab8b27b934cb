"""Shrinking a failure toward the nominal scenario: it keeps the failure's clause, never moves a
parameter away from nominal, spends at most its budget, and says what still matters."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from hritest import search as qd
from hritest.cli import app
from hritest.corpus import load_entry
from hritest.domain import compile_spec
from hritest.evaluate import evaluate
from hritest.shrink import ShrinkError, shrink
from hritest.spec import load_spec

# Nominal goals 0.16 m apart and no noise: the nominal scenario passes (objective 2.8 < 8).
G0X = "{name: g0x, bind: task.g0x, bounds: [0.52, 0.68]"
G1X = "{name: g1x, bind: task.g1x, bounds: [0.52, 0.68]"
NOMINAL = {
    G0X + "}": G0X + ", nominal: 0.52}",
    G1X + "}": G1X + ", nominal: 0.68}",
    "failure: objective >= 8": "failure: objective >= 8 or min_goal_distance > 0.25",
}


@pytest.fixture
def domain(toy_spec):
    text = toy_spec()
    spec = text.read_text()
    for old, new in NOMINAL.items():
        spec = spec.replace(old, new)
    return compile_spec(load_spec(toy_spec(text=spec)))


def failures(domain, clause: str, count: int) -> list[np.ndarray]:
    """``count`` random failing thetas for which ``clause`` holds."""
    rng = np.random.default_rng(0)
    found = []
    while len(found) < count:
        theta = rng.uniform(domain.space.lower, domain.space.upper)
        if any(c.text == clause for c in evaluate(domain, theta, seed=0).fired):
            found.append(theta)
    return found


def distances(domain, theta) -> np.ndarray:
    return np.abs(np.asarray(theta) - domain.nominal)


def test_the_nominal_scenario_passes(domain):
    assert not evaluate(domain, domain.nominal, seed=0).failure


@pytest.mark.parametrize("clause", ["objective >= 8", "min_goal_distance > 0.25"])
def test_a_shrunk_failure_keeps_its_clause_and_moves_only_toward_nominal(domain, clause):
    for theta in failures(domain, clause, 3):
        shrunk = shrink(domain, theta, seed=0, clause=clause, budget=60)
        again = evaluate(domain, shrunk.theta, seed=0)
        assert again.ok and any(c.text == clause for c in again.fired)
        assert np.all(distances(domain, shrunk.theta) <= distances(domain, theta) + 1e-12)
        assert len(shrunk.off_nominal(shrunk.theta)) <= len(shrunk.off_nominal(theta))
        assert 1 < shrunk.evaluations <= 60


def test_what_still_matters_is_what_the_failure_needs(domain):
    # Close goals fail without any noise: the noise goes back to nominal, the goals stay apart from it.
    theta = np.array([0.6, 0.05, 0.61, 0.06, 0.04, -0.03, 0.02])
    shrunk = shrink(domain, theta, seed=0, clause="objective >= 8")
    assert "noise" in shrunk.off_nominal(theta) and "noise" not in shrunk.off_nominal(shrunk.theta)
    assert {"g0x", "g1x"} & set(shrunk.off_nominal(shrunk.theta))
    assert "noise nominal" in shrunk.steps


def test_the_budget_bounds_the_simulations(domain):
    [theta] = failures(domain, "objective >= 8", 1)
    assert shrink(domain, theta, seed=0, budget=3).evaluations <= 3


def test_a_passing_scenario_or_a_clause_that_does_not_hold_is_refused(domain):
    with pytest.raises(ShrinkError, match="not a failure"):
        shrink(domain, domain.nominal, seed=0)
    [theta] = failures(domain, "objective >= 8", 1)  # goals within 0.1 m: the other clause cannot hold
    with pytest.raises(ShrinkError, match="does not hold"):
        shrink(domain, theta, seed=0, clause="min_goal_distance > 0.25")


def test_the_command_prints_what_still_matters_and_stores_the_shrunk_scenario(domain, tmp_path):
    spec = tmp_path / "spec.yaml"  # the domain fixture's spec
    qd.start(
        spec_file=spec, out=tmp_path / "run", algorithm="random", budget=100, seed=0, backend=qd.Backend(workers=1)
    )
    failure = yaml.safe_load((tmp_path / "run" / "failures.yaml").read_text())["failures"][0]
    result = CliRunner().invoke(app, ["shrink", str(tmp_path / "run"), "--failure", str(failure["id"]), "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    assert data["original_theta"] == failure["theta_raw"] and len(data["theta"]) == len(data["original_theta"])
    assert data["clause"] in {"objective >= 8", "min_goal_distance > 0.25"} and 1 <= data["evaluations"] <= 100
    assert json.loads((tmp_path / "run" / "shrunk" / f"{failure['id']}.json").read_text())["theta"] == data["theta"]

    result = CliRunner().invoke(app, ["shrink", str(tmp_path / "run"), "--failure", "99999"])
    assert result.exit_code == 2 and "99999" in result.output


def test_promote_shrink_keeps_the_simplest_version_of_each_failure(domain, tmp_path):
    qd.start(
        spec_file=tmp_path / "spec.yaml", out=tmp_path / "run", algorithm="random", budget=100, seed=0,
        backend=qd.Backend(workers=1),
    )  # fmt: skip
    result = CliRunner().invoke(
        app, ["promote", str(tmp_path / "run"), "--top", "1", "--shrink", "--to", str(tmp_path / "corpus")]
    )
    assert result.exit_code == 0, result.output
    [path] = (tmp_path / "corpus" / "toy").glob("*.yaml")
    entry = load_entry(path)
    [failure] = [
        f
        for f in yaml.safe_load((tmp_path / "run" / "failures.yaml").read_text())["failures"]
        if f["id"] == entry.origin["evaluation"]
    ]
    shrunk = json.loads((tmp_path / "run" / "shrunk" / f"{failure['id']}.json").read_text())
    assert list(entry.theta.values()) == pytest.approx(shrunk["theta"]) and entry.origin["shrunk"] is True
    assert evaluate(domain, np.array(shrunk["theta"]), seed=entry.seed).failure
    assert any(row["matters"] for row in shrunk["parameters"].values())  # the nominal passes: something is needed
