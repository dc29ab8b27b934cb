"""Bad specs give one clear message with file, line, column and field path; good ones load."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from hritest.domain import compile_spec
from hritest.errors import SpecError
from hritest.spec import load_spec

# Placed objects for the toy spec, which has none: a workspace region and one box.
PLACED = (
    "workspace:\n  regions:\n    - {name: ws1, x: [0.5, 0.7], y: [-0.1, 0.2]}\n"
    "objects:\n  - {name: goal0, half_size: [0.032, 0.032, 0.032], position: [0.6, 0.05, 0.96]}\n"
)


def error_of(path: Path, *, compile: bool = True) -> SpecError:
    with pytest.raises(SpecError) as info:
        (compile_spec if compile else lambda spec: spec)(load_spec(path))
    return info.value


def line_of(path: Path, text: str) -> int:
    """1-based line of the first line containing ``text``."""
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if text in line:
            return number
    raise AssertionError(f"{text!r} not in {path}")


def only_issue(error: SpecError):
    assert len(error.issues) == 1, str(error)
    return error.issues[0]


def test_the_toy_spec_loads_and_compiles(toy_spec):
    domain = compile_spec(load_spec(toy_spec()))
    assert domain.space.dim == 7
    assert domain.archive_dims == (16, 16)


@pytest.mark.parametrize(
    ("old", "new", "field", "marker", "words"),
    [
        # An unknown key, pointed at and with the allowed keys listed.
        (
            "  time_limit: 10.0\n",
            "  time_limit: 10.0\n  timelimit: 3\n",
            "task.timelimit",
            "timelimit:",
            ["unknown key 'timelimit'", "time_limit"],
        ),
        # A wrong type.
        (
            "  time_limit: 10.0\n",
            "  time_limit: ten\n",
            "task.time_limit",
            "time_limit: ten",
            ["valid number", "'ten'"],
        ),
        # A measure range with lo >= hi.
        (
            "range: [0, 0.32], cells: 16",
            "range: [0.32, 0.1], cells: 16",
            "measures[0].range",
            "0.32, 0.1",
            ["lower end must be below the upper end"],
        ),
        # A parameter bound to an unknown object.
        ("bind: task.g1x", "bind: goal9.x", "parameters[2].bind", "goal9.x", ["unknown target 'goal9'"]),
        # A constraint naming an unknown region: needs an inside constraint.
        (
            "constraints:\n",
            PLACED + "constraints:\n  - {type: inside, objects: [goal0], regions: [ws7]}\n",
            "constraints[0].regions[0]",
            "ws7",
            ["unknown region 'ws7'", "ws1"],
        ),
        # A duplicate name.
        (
            "{name: variation,",
            "{name: goal_distance,",
            "measures[1].name",
            "{name: goal_distance, expr: norm",
            ["duplicate name 'goal_distance'"],
        ),
        # A measure with lo >= hi written as equal ends.
        ("range: [0, 0.087]", "range: [0.087, 0.087]", "measures[1].range", "0.087, 0.087", ["lower end"]),
        # A box that is not a box.
        (
            "constraints:\n",
            PLACED.replace("half_size: [0.032, 0.032", "half_size: [0.032, -0.032") + "constraints:\n",
            "objects[0].half_size",
            "-0.032",
            ["every half size must be positive"],
        ),
        # Unknown constraint type.
        ("- {type: bounds,", "- {type: fence,", "constraints[0]", "type: fence", ["inside", "no_overlap"]),
    ],
)
def test_structural_and_reference_errors_point_at_the_field(toy_spec, old, new, field, marker, words):
    path = toy_spec(old, new)
    issue = only_issue(error_of(path))
    assert issue.field == field
    assert issue.location.file == str(path)
    assert issue.location.line == line_of(path, marker)
    for word in words:
        assert word in issue.message, issue.message
    assert re.match(rf"{re.escape(str(path))}:\d+:\d+: {re.escape(field)}: ", str(issue))


@pytest.mark.parametrize(
    ("expression", "words"),
    [
        ("completion_tme", ["unknown name 'completion_tme'", "completion_time"]),
        ("completion_time.real", ["attribute access is not allowed"]),
        ("__import__('os')", ["calling '__import__' is not allowed"]),
        ("exp(completion_time)", ["calling 'exp' is not allowed", "norm"]),
        ("[completion_time][0]", ["only a parameter group may be indexed"]),
        ("completion_time +", ["not a valid expression"]),
        ("lambda: 1", ["not allowed"]),
        ("completion_time > 3", ["is a condition"]),
    ],
)
def test_objective_expressions_are_whitelisted(toy_spec, expression, words):
    path = toy_spec(
        "expr: completion_time", f"expr: {expression!r}" if "'" not in expression else f'expr: "{expression}"'
    )
    issue = only_issue(error_of(path))
    assert issue.field == "objective.expr"
    assert issue.location.line == line_of(path, "expr: " + ('"' if "'" in expression else "'"))
    for word in words:
        assert word in issue.message, issue.message


def test_failure_must_be_a_condition_over_known_names(toy_spec):
    issue = only_issue(error_of(toy_spec("failure: objective >= 8", "failure: objective * 2")))
    assert issue.field == "failure" and "not a condition" in issue.message
    issue = only_issue(error_of(toy_spec("failure: objective >= 8", "failure: objectiv >= 8")))
    assert issue.field == "failure" and "unknown name 'objectiv'" in issue.message


def test_a_plugin_that_does_not_import(toy_spec, tmp_path):
    (tmp_path / "broken.py").write_text("import not_a_module_anywhere\n")
    path = toy_spec("policy: toy_plugins.py:ToyRobot", "policy: broken.py:Robot")
    issue = only_issue(error_of(path))
    assert issue.field == "robot.policy"
    assert issue.location.line == line_of(path, "broken.py:Robot")
    assert "does not import" in issue.message and "not_a_module_anywhere" in issue.message


@pytest.mark.parametrize(
    ("ref", "words"),
    [
        ("no_such_plugin", ["unknown robot plugin 'no_such_plugin'", "module:Class"]),
        ("toy_plugins.py:Missing", ["has no class 'Missing'", "ToyRobot"]),
        ("toy_plugins.py:ToyHuman", ["declares kind='human'"]),
        ("missing_file.py:Robot", ["does not exist"]),
        ("no_such_package.mod:Robot", ["does not import", "No module named"]),
    ],
)
def test_plugin_references(toy_spec, ref, words):
    issue = only_issue(error_of(toy_spec("policy: toy_plugins.py:ToyRobot", f"policy: {ref}")))
    assert issue.field == "robot.policy"
    for word in words:
        assert word in issue.message, issue.message


def test_plugin_params_and_theta_bindings_are_checked(toy_spec):
    issue = only_issue(error_of(toy_spec("time_limit: 10.0\n", "time_limit: 10.0\n  params: {scael: 2}\n")))
    assert issue.field == "task.params.scael"
    issue = only_issue(error_of(toy_spec("bind: human.noise", "bind: human.nosie")))
    assert issue.field == "parameters[4].bind" and "has no parameter 'nosie'" in issue.message


def test_yaml_syntax_error(toy_spec):
    path = toy_spec("measures:\n", "measures: [\n")
    issue = only_issue(error_of(path))
    assert "not valid YAML" in issue.message
    assert issue.location is not None and issue.location.line >= line_of(path, "measures: [")


def test_empty_file(toy_spec):
    issue = only_issue(error_of(toy_spec(text="# nothing here\n")))
    assert "is empty" in issue.message


@pytest.mark.parametrize("text", ["just some words\n", "- a\n- list\n"])
def test_not_a_mapping(toy_spec, text):
    issue = only_issue(error_of(toy_spec(text=text)))
    assert "is not a hritest spec" in issue.message


def test_binary_file(tmp_path):
    path = tmp_path / "spec.yaml"
    path.write_bytes(bytes(range(256)))
    issue = only_issue(error_of(path))
    assert "UTF-8" in issue.message or "not valid YAML" in issue.message


def test_missing_file(tmp_path):
    issue = only_issue(error_of(tmp_path / "nope.yaml"))
    assert "no such file" in issue.message


def test_missing_required_key_points_at_parent(toy_spec):
    path = toy_spec("  time_limit: 10.0\n", "")
    issue = only_issue(error_of(path))
    assert issue.field == "task" and "missing required key 'time_limit'" in issue.message
    assert issue.location.line == line_of(path, "task:") + 1  # the mapping under 'task:'


def test_every_issue_is_reported_at_once(toy_spec):
    path = toy_spec("constraints:\n", PLACED + "constraints:\n")
    path.write_text(
        path.read_text()
        .replace("bind: task.g1x", "bind: goal9.x")
        .replace("cells: 16}\n  - {name: variation", "cells: 0}\n  - {name: variation")
    )
    error = error_of(path)
    assert {issue.field for issue in error.issues} == {"measures[0].cells"}  # structure is checked first
    path.write_text(
        path.read_text()
        .replace("cells: 0}", "cells: 16}")
        .replace("regions:\n", "regions:\n    - {name: ws1, x: [0, 1], y: [0, 1]}\n")
    )
    error = error_of(path)
    assert {issue.field for issue in error.issues} == {"workspace.regions[1].name", "parameters[2].bind"}


def test_search_settings_must_match_theta(toy_spec):
    issue = only_issue(error_of(toy_spec("budget: 500", "budget: 500\n  emitter: {x0: [0, 0]}")))
    assert issue.field == "search.emitter.x0" and "7 components" in issue.message


def test_unknown_keys_do_not_hide_the_name_checks(toy_spec):
    path = toy_spec("  time_limit: 10.0\n", "  time_limit: 10.0\n  timelimit: 3\n")
    path.write_text(path.read_text().replace("bind: task.g1x", "bind: goal9.x").replace("budget: 500", "budgt: 500"))
    error = error_of(path, compile=False)
    assert [issue.field for issue in error.issues] == ["task.timelimit", "search.budgt", "parameters[2].bind"]


def test_echoed_input_is_cut_short(toy_spec):
    issue = only_issue(error_of(toy_spec("time_limit: 10.0", "time_limit: " + "x" * 100_000)))
    assert issue.field == "task.time_limit" and len(issue.message) < 200
