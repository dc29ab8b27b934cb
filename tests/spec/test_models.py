"""Per-field checks: every number finite and not a boolean, seeds in range, parameters named in their errors."""

from __future__ import annotations

import pytest

from hritest.errors import SpecError
from hritest.spec import load_spec
from hritest.spec.models import MAX_BATCH, MAX_SEED, MAX_TICKS


def only_issue(path):
    with pytest.raises(SpecError) as info:
        load_spec(path)
    assert len(info.value.issues) == 1, str(info.value)
    return info.value.issues[0]


PLACED = (
    "workspace:\n  table: {center: [0.5, 0.3, 0.8], half_size: [0.4, 0.5, 0.02]}\n"
    "  regions:\n    - {name: ws1, x: [0.5, 0.7], y: [-0.1, 0.2]}\n"
    "objects:\n  - {name: goal0, half_size: [0.03, 0.03, 0.03], position: [0.6, 0.05, 0.96]}\n"
    "constraints:\n"
)


@pytest.mark.parametrize("bad", [".nan", ".inf", "-.inf"])
@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ("bounds: [0.52, 0.68]}\n  - {name: g0y", "bounds: [0.52, @]}\n  - {name: g0y", "parameters[0].bounds[1]"),
        (
            "bind: task.g1y, bounds: [-0.08, 0.18]}",
            "bind: task.g1y, bounds: [-0.08, 0.18], nominal: @}",
            "parameters[3].nominal",
        ),
        ("range: [0, 10]", "range: [@, 10]", "objective.range[0]"),
        ("range: [0, 10]", "range: [0, 10]\n  repair_weight: @", "objective.repair_weight"),
        ("range: [0, 0.32], cells: 16", "range: [0, @], cells: 16", "measures[0].range[1]"),
        ("time_limit: 10.0", "time_limit: @", "task.time_limit"),
        ("dt: 0.025", "dt: @", "task.dt"),
        ("budget: 500", "budget: 500\n  emitter: {sigma0: @}", "search.emitter.sigma0"),
        ("budget: 500", "budget: 500\n  emitter: {learning_rate: @}", "search.emitter.learning_rate"),
        ("budget: 500", "budget: 500\n  emitter: {x0: [0.6, 0, 0.6, 0, 0, 0, @]}", "search.emitter.x0[6]"),
        ("budget: 500", "budget: 500\n  map_elites: {sigma: @}", "search.map_elites.sigma"),
        ("budget: 500", "budget: 500\n  surrogate: {learning_rate: @}", "search.surrogate.learning_rate"),
        ("constraints:\n", PLACED.replace("-0.1, 0.2", "-0.1, @"), "workspace.regions[0].y[1]"),
        ("constraints:\n", PLACED.replace("0.6, 0.05, 0.96", "0.6, @, 0.96"), "objects[0].position[1]"),
        ("constraints:\n", PLACED.replace("0.4, 0.5, 0.02", "0.4, @, 0.02"), "workspace.table.half_size[1]"),
    ],
)
def test_numbers_must_be_finite(toy_spec, old, new, field, bad):
    issue = only_issue(toy_spec(old, new.replace("@", bad)))
    assert issue.field == field
    assert f"expected a finite number, not {float(bad.replace('.', ''))}" in issue.message, issue.message


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ("bounds: [-0.05, 0.05]", "bounds: [true, 2]", "parameters[4].bounds[0]"),
        ("budget: 500", "budget: true", "search.budget"),
        ("cells: 16}\n  - {name: variation", "cells: yes}\n  - {name: variation", "measures[0].cells"),
        ("size: 3", "size: true", "parameters[4].size"),
        ("time_limit: 10.0", "time_limit: on", "task.time_limit"),
        ("budget: 500", "budget: 500\n  seed: false", "search.seed"),
        ("range: [0, 10]", "range: [0, 10]\n  repair_weight: true", "objective.repair_weight"),
    ],
)
def test_booleans_are_not_numbers(toy_spec, old, new, field):
    issue = only_issue(toy_spec(old, new))
    assert issue.field == field
    assert "expected a number, not " in issue.message, issue.message


@pytest.mark.parametrize("seed", [-1, MAX_SEED + 1, 10**40])
def test_seeds_outside_what_numpy_and_torch_take(toy_spec, seed):
    issue = only_issue(toy_spec("budget: 500", f"budget: 500\n  seed: {seed}"))
    assert issue.field == "search.seed"
    assert "a seed is a whole number from 0 to 2**63 - 1" in issue.message


def test_the_largest_seed_is_accepted(toy_spec):
    assert load_spec(toy_spec("budget: 500", f"budget: 500\n  seed: {MAX_SEED}")).search.seed == MAX_SEED


def test_reversed_bounds_name_the_parameter(toy_spec):
    issue = only_issue(toy_spec("bounds: [-0.05, 0.05]", "bounds: [0.05, -0.05]"))
    assert issue.field == "parameters[4].bounds"
    assert "parameter 'noise' has bounds [0.05, -0.05]" in issue.message and "[low, high]" in issue.message


def test_a_group_of_size_zero_names_the_parameter_and_its_bounds(toy_spec):
    issue = only_issue(toy_spec("size: 3", "size: 0"))
    assert issue.field == "parameters[4].size"
    assert "parameter 'noise' (bounds [-0.05, 0.05]) has size 0" in issue.message


def test_a_nominal_outside_the_bounds_names_the_parameter(toy_spec):
    issue = only_issue(toy_spec("bounds: [-0.05, 0.05]", "bounds: [-0.05, 0.05], nominal: [0, 0, 3]"))
    assert issue.field == "parameters[4].nominal"
    assert "parameter 'noise': nominal [3.0] lies outside the bounds [-0.05, 0.05]" in issue.message


@pytest.mark.parametrize(
    ("old", "new", "field", "words"),
    [
        (
            "time_limit: 10.0",
            "time_limit: 1.0e+12",
            "task",
            f"40,000,000,000,000 ticks; an episode has 1 to {MAX_TICKS:,}",
        ),
        ("dt: 0.025", "dt: 30", "task", "0 ticks"),
        ("budget: 500", "budget: 1000000000000", "search.budget", "less than or equal to 1000000000"),
        ("budget: 500", "budget: 500\n  emitter: {emitters: 100000}", "search.emitter.emitters", "less than or equal"),
        ("budget: 500", "budget: 500\n  random: {batch_size: 1000000000}", "search.random.batch_size", f"{MAX_BATCH}"),
        (
            "budget: 500",
            "budget: 500\n  emitter: {batch_size: 1000000000}",
            "search.emitter.batch_size",
            f"{MAX_BATCH}",
        ),
    ],
)
def test_sizes_no_episode_or_search_can_hold(toy_spec, old, new, field, words):
    issue = only_issue(toy_spec(old, new))
    assert issue.field == field
    assert words in issue.message, issue.message


@pytest.mark.parametrize(
    ("old", "new", "field", "words"),
    [
        ("time_limit: 10.0\n", "time_limit: 10.0\n  params: {scale: .nan}\n", "task.params.scale", "not nan"),
        (
            "policy: toy_plugins.py:ToyHuman\n",
            "policy: toy_plugins.py:ToyHuman\n  params: {speed: 1, gains: {p: [1, -.inf]}}\n",
            "human.params.gains.p[1]",
            "not -inf",
        ),
    ],
)
def test_plugin_params_are_finite(toy_spec, old, new, field, words):
    issue = only_issue(toy_spec(old, new))
    assert issue.field == field and f"expected a finite number, {words}" in issue.message, issue.message


def test_every_non_finite_plugin_param_is_named_at_its_own_line(toy_spec):
    path = toy_spec(
        "policy: toy_plugins.py:ToyHuman\n",
        "policy: toy_plugins.py:ToyHuman\n  params:\n    speed: .nan\n    gains: [1, .inf]\n",
    )
    with pytest.raises(SpecError) as info:
        load_spec(path)
    lines = path.read_text().splitlines()
    found = {issue.field: issue for issue in info.value.issues}
    assert sorted(found) == ["human.params.gains[1]", "human.params.speed"], str(info.value)
    assert lines[found["human.params.speed"].location.line - 1].strip() == "speed: .nan"
    assert lines[found["human.params.gains[1]"].location.line - 1].strip() == "gains: [1, .inf]"
