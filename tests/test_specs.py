"""The shipped specs: each validates and simulates end to end; the CLI's show, simulate and repair."""

from __future__ import annotations

import json
import math
import re
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hritest.cli import app
from hritest.domain import compile_spec
from hritest.evaluate import evaluate
from hritest.spec import load_spec

runner = CliRunner()
SPECS = Path(__file__).parent.parent / "specs"
ALL = sorted(SPECS.glob("*.yaml"))
EXPECTED = {"collab", "collab_human", "collab_success", "collab_wait", "teleop", "teleop_blend"}
TELEOP = SPECS / "teleop.yaml"
EASY = [0.66, -0.06, 0.54, 0.16, 0, 0, 0, 0, 0]  # goals far apart: the robot helps the user quickly
DISTRACTOR = [0.66, 0.05, 0.55, 0.05, 0, 0, 0, 0, 0]  # goal1 on the user's path: never reaches goal0


@cache
def domain(path: Path):
    return compile_spec(load_spec(path))


def text_of(output: str) -> str:
    """CLI output with rich's box drawing removed and whitespace collapsed (panels wrap lines)."""
    return " ".join(re.sub(r"[\u2500-\u257f]", " ", output).split())


def theta_arg(values) -> str:
    return ",".join(repr(float(v)) for v in values)


def test_every_shipped_spec_validates():
    assert {p.stem for p in ALL} >= EXPECTED
    result = runner.invoke(app, ["validate", *map(str, ALL)])
    assert result.exit_code == 0, result.output
    for path in ALL:
        assert f"ok {path}" in result.output


def test_the_papers_specs_keep_its_surrogate_schedule_and_others_get_the_flat_one():
    # The paper's experiments retrain on all data and run every inner iteration, however long it
    # takes (benchmarks compare with its numbers); a spec that says nothing gets the schedule whose
    # cost follows its data and is cut to a fifth of the run's time.
    for path in ALL:
        surrogate = load_spec(path).search.surrogate
        paper = (surrogate.training, surrogate.inner_stall, surrogate.time_share) == ("paper", None, 1)
        assert paper == (path.stem in EXPECTED), path
    handover = load_spec(SPECS / "handover.yaml").search.surrogate
    assert (handover.training, handover.time_share) == ("incremental", 0.2)


@pytest.mark.parametrize("draw", [0, 1])
@pytest.mark.parametrize("path", ALL, ids=[p.stem for p in ALL])
def test_every_spec_simulates_end_to_end_on_random_theta(path, draw):
    d = domain(path)
    rng = np.random.default_rng([draw, sum(map(ord, path.stem))])
    theta = rng.uniform(d.space.lower, d.space.upper)
    evaluation = evaluate(d, theta, seed=draw)
    assert evaluation.status == "ok", evaluation.message
    lo, hi = d.spec.objective.range
    assert math.isfinite(evaluation.objective) and lo <= evaluation.objective <= hi
    assert evaluation.measures.shape == (len(d.measures),)
    assert np.all(np.isfinite(evaluation.measures))
    assert set(d.task_cls.metrics) <= set(evaluation.metrics)
    assert all(math.isfinite(v) for v in evaluation.metrics.values())
    assert d.repair(evaluation.theta_repaired).cost == pytest.approx(0.0, abs=1e-9)  # repaired is valid


def test_show_prints_the_collaboration_layout():
    result = runner.invoke(app, ["show", str(SPECS / "collab.yaml")])
    assert result.exit_code == 0, result.output
    text = text_of(result.output)
    assert "theta: 6 components" in text
    for index, (label, lower, upper) in enumerate(
        [
            ("x0", "0.138", "0.68"),
            ("y0", "-0.08", "0.756"),
            ("x1", "0.138", "0.68"),
            ("y1", "-0.08", "0.756"),
            ("x2", "0.138", "0.68"),
            ("y2", "-0.08", "0.756"),
        ]
    ):
        bind = f"goal{index // 2}.{label[0]}"
        assert f"{index} {label} {bind} {lower} {upper}" in text
    for words in (
        "CollaborationTask",
        "CollabRobot",
        "MdpHuman",
        "27 x 65 cells",
        "goal_distance min_goal_distance [0.05, 0.32] 27",
        "failure when objective >= 60",
        "regions=['ws1', 'ws2']",
    ):
        assert words in text, words


# --- simulate ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("path", "theta", "code"),
    [
        (TELEOP, EASY, 0),
        (TELEOP, DISTRACTOR, 1),  # a failure: objective >= 10
        (SPECS / "collab_wait.yaml", [0.4, 0.3, 0.6, 0.1, 0.2, 0.7], 0),  # needs repair
    ],
    ids=["teleop-ok", "teleop-failure", "collab-repaired"],
)
def test_simulate_json_matches_evaluate(path, theta, code):
    result = runner.invoke(app, ["simulate", str(path), "--theta", theta_arg(theta), "--json", "--seed", "3"])
    assert result.exit_code == code, result.output
    data = json.loads(result.stdout)
    expected = evaluate(domain(path), np.array(theta, dtype=float), seed=3)
    assert data["status"] == expected.status == "ok"
    assert data["failure"] is expected.failure is (code == 1)
    assert data["objective"] == pytest.approx(expected.objective, abs=1e-12)
    assert data["search_objective"] == pytest.approx(expected.search_objective, abs=1e-12)
    assert list(data["measures"]) == [m.name for m in domain(path).measures]
    assert list(data["measures"].values()) == pytest.approx(expected.measures.tolist(), abs=1e-12)
    assert data["metrics"] == pytest.approx(expected.metrics, abs=1e-12)
    assert data["theta"] == pytest.approx(theta)
    assert data["theta_repaired"] == pytest.approx(expected.theta_repaired.tolist(), abs=1e-12)
    assert data["repair_cost"] == pytest.approx(expected.repair_cost, abs=1e-12)
    assert data["regions"] == expected.regions
    assert data["seed"] == 3


# --- repair --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("path", "theta", "status"),
    [
        (SPECS / "collab.yaml", [0.4, 0.3, 0.4, 0.3, 0.4, 0.3], "repaired"),  # between the regions, stacked
        (SPECS / "collab.yaml", [0.55, -0.05, 0.65, 0.15, 0.2, 0.6], "unchanged"),
        (TELEOP, [0.75, 0.05, 0.6, -0.2, 0.1, 0, 0, 0, 0], "ok"),  # out of bounds: clipped
    ],
    ids=["collab-moved", "collab-valid", "teleop-clipped"],
)
def test_repair_json_matches_the_domains_repair(path, theta, status):
    result = runner.invoke(app, ["repair", str(path), "--theta", theta_arg(theta), "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    expected = domain(path).repair(np.array(theta, dtype=float))
    assert data["status"] == expected.status == status
    assert data["theta"] == pytest.approx(theta)
    assert data["repaired"] == pytest.approx(expected.theta.tolist(), abs=1e-12)
    assert data["cost"] == pytest.approx(expected.cost, abs=1e-12)
    assert data["regions"] == expected.regions
    if status == "unchanged":
        assert data["repaired"] == pytest.approx(theta) and data["cost"] == 0.0
    else:
        assert data["cost"] > 0.0 and data["repaired"] != pytest.approx(theta)


@pytest.mark.parametrize("command", ["simulate", "repair"])
def test_a_theta_of_the_wrong_length_exits_2_naming_the_labels(command):
    result = runner.invoke(app, [command, str(TELEOP), "--theta", "0.6,0.05,0.6"])
    assert result.exit_code == 2
    text = text_of(result.output)
    assert "got 3 values" in text
    assert "needs 9: g0x, g0y, g1x, g1y, noise[0], noise[1], noise[2], noise[3], noise[4]" in text
