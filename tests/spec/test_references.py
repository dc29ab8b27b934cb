"""Whole-spec checks: sizes a search cannot allocate, names an expression cannot mean, indexes past the end."""

from __future__ import annotations

import pytest

from hritest.domain import compile_spec
from hritest.errors import SpecError
from hritest.spec import load_spec
from hritest.spec.references import MAX_CELLS, MAX_DIM


def only_issue(path, *, compile: bool = False):
    with pytest.raises(SpecError) as info:
        (compile_spec if compile else lambda spec: spec)(load_spec(path))
    assert len(info.value.issues) == 1, str(info.value)
    return info.value.issues[0]


def test_an_archive_too_large_to_allocate(toy_spec):
    issue = only_issue(toy_spec("range: [0, 0.32], cells: 16", "range: [0, 0.32], cells: 100000000"))
    assert issue.field == "measures"
    assert f"100,000,000 x 16 = 1,600,000,000 cells; at most {MAX_CELLS:,}" in issue.message


def test_a_theta_too_long_for_a_search(toy_spec):
    issue = only_issue(toy_spec("size: 3", f"size: {MAX_DIM}"))
    assert issue.field == "parameters"
    assert f"theta has {MAX_DIM + 4:,} components; a search handles at most {MAX_DIM:,}" in issue.message


@pytest.mark.parametrize(("name", "what"), [("lambda", "a Python keyword"), ("norm", "a function of expressions")])
def test_names_no_expression_can_refer_to(toy_spec, name, what):
    issue = only_issue(toy_spec("{name: variation,", f"{{name: {name},"))
    assert issue.field == "measures[1].name"
    assert f"{name!r} is {what}" in issue.message


@pytest.mark.parametrize(
    ("expression", "words"),
    [
        ("noise[3]", "noise[3] is past the end of 'noise', which has 3 components: noise[0] to noise[2]"),
        ("g0x[0]", "'g0x' is one number, not a group: write g0x, not g0x[0]"),
    ],
)
def test_an_index_no_scenario_can_satisfy(toy_spec, expression, words):
    issue = only_issue(toy_spec("expr: norm(noise)", f"expr: '{expression}'"))
    assert issue.field == "measures[1].expr"
    assert words in issue.message


def test_an_index_into_a_measure_in_the_failure_condition(toy_spec):
    issue = only_issue(toy_spec("failure: objective >= 8", "failure: variation[1] >= 8"))
    assert issue.field == "failure" and "'variation' is one number" in issue.message


def test_a_parameter_that_shadows_a_metric_names_both(toy_spec):
    path = toy_spec("{name: g0x,", "{name: completion_time,")
    path.write_text(path.read_text().replace("[[g0x, g1x]", "[[completion_time, g1x]"))
    issue = only_issue(path, compile=True)
    assert issue.field == "parameters[0].name"
    assert (
        "parameter 'completion_time' has the name of the task's metric 'completion_time' (toy_plugins.py:ToyTask)"
        in issue.message
    )


def test_a_measure_that_shadows_a_metric(toy_spec):
    issue = only_issue(toy_spec("{name: variation,", "{name: human_variation,"), compile=True)
    assert issue.field == "measures[1].name"
    assert "measure 'human_variation' (norm(noise)) has the name of the task's metric" in issue.message


def test_a_measure_that_is_its_metric_hides_nothing(toy_spec):
    path = toy_spec(
        "{name: goal_distance, expr: min_goal_distance,", "{name: min_goal_distance, expr: min_goal_distance,"
    )
    assert compile_spec(load_spec(path)).measures[0].name == "min_goal_distance"
