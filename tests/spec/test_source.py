"""Hostile YAML fails fast with one short message: duplicate keys, alias bombs, deep nesting."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from hritest.cli import app
from hritest.errors import SpecError
from hritest.spec import load_spec
from hritest.spec.source import MAX_DEPTH, MAX_VALUES


def error_of(path: Path) -> SpecError:
    with pytest.raises(SpecError) as info:
        load_spec(path)
    return info.value


def alias_bomb(levels: int) -> str:
    """YAML whose last anchor expands to 9**levels strings: a few hundred bytes, billions of values."""
    lines = ['lol0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"lol{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]" for i in range(1, levels + 1)]
    return "\n".join(lines) + "\n"


def test_a_duplicate_key_names_both_lines(toy_spec):
    path = toy_spec("  budget: 500\n", "  budget: 500\n  budget: 600\n")
    (issue,) = error_of(path).issues
    assert issue.field == "search.budget"
    first = path.read_text().splitlines().index("  budget: 500") + 1
    assert issue.location.line == first + 1
    assert f"duplicate key 'budget' (first at line {first})" in issue.message


def test_duplicate_keys_are_reported_with_the_other_problems(toy_spec):
    path = toy_spec("  budget: 500\n", "  budget: 500\n  budget: 600\n  sed: 3\n")
    assert {issue.field for issue in error_of(path).issues} == {"search.budget", "search.sed"}


def test_an_alias_bomb_is_refused_before_it_expands(toy_spec):
    path = toy_spec("search:\n", alias_bomb(9) + "search:\n")
    error = error_of(path)
    assert len(str(error)) < 500
    assert f"expands to more than {MAX_VALUES:,} values through YAML aliases" in str(error)


def test_an_alias_bomb_in_a_field_is_not_echoed(toy_spec):
    # Small enough to pass the expansion limit; the type error must not print it back.
    path = toy_spec("description: analytic toy domain for tests and benchmarks", alias_bomb(3) + "description: *a3")
    error = error_of(path)
    assert any(issue.field == "description" for issue in error.issues)
    assert len(str(error)) < 2000


def test_a_few_aliases_are_fine(toy_spec):
    path = toy_spec("range: [0, 10]", "range: &r [0, 10]")
    path.write_text(path.read_text().replace("range: [0, 0.32]", "range: *r"))
    assert load_spec(path).measures[0].range == (0, 10)


def test_an_alias_that_contains_itself(toy_spec):
    path = toy_spec("search:\n", "loop: &loop [1, *loop]\nsearch:\n")
    (issue,) = error_of(path).issues
    assert "alias that contains itself" in issue.message and issue.field == "loop[1]"


@pytest.mark.parametrize("depth", [MAX_DEPTH + 1, 5000])
def test_deep_nesting_is_a_message_not_a_recursion_error(toy_spec, depth):
    path = toy_spec("search:\n", "deep: " + "[" * depth + "]" * depth + "\nsearch:\n")
    (issue,) = error_of(path).issues
    assert f"nests more than {MAX_DEPTH} levels deep" in issue.message


def test_an_integer_too_long_to_read(toy_spec):
    (issue,) = error_of(toy_spec("budget: 500", "budget: " + "9" * 5000)).issues
    assert "cannot be read" in issue.message


def test_validate_prints_a_short_message_for_an_alias_bomb(toy_spec):
    path = toy_spec("search:\n", alias_bomb(9) + "search:\n")
    result = CliRunner().invoke(app, ["validate", str(path)])
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert len(result.output) < 1000
    assert re.search(rf"{re.escape(str(path))}:\d+:\d+: lol\d", result.output.replace("\n", ""))
