"""``hritest check``: a ready spec passes; each broken promise of the contract is one finding with a fix."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from hritest.check import check_spec
from hritest.cli import app

runner = CliRunner()


def broken_toy(toy_spec, tmp_path, old: str, new: str):
    """The toy spec beside a toy plugin file with ``old`` replaced by ``new``."""
    spec = toy_spec()
    plugins = tmp_path / "toy_plugins.py"
    text = plugins.read_text()
    assert text.count(old) == 1, old
    plugins.write_text(text.replace(old, new))
    return spec


def test_a_ready_spec_passes(toy_spec):
    result = runner.invoke(app, ["check", str(toy_spec())])
    assert result.exit_code == 0, result.output
    assert "same seed, same outcome" in result.output and "ready to search" in result.output
    assert "one scenario takes" in result.output


@pytest.mark.parametrize(
    ("old", "new", "check", "words"),
    [
        # A declared metric never reported.
        (
            '"human_variation": variation,',
            "",
            "metric_error",
            ["ToyTask (", "toy_plugins.py:", "declares metric 'human_variation' but its Rollout.metrics lacks it"],
        ),
        # A grid of the wrong shape.
        (
            "grids: ClassVar[dict[str, tuple[int, int]]] = {}",
            'grids = {"robot": (32, 32)}',
            "plugin_error",
            ["toy_plugins.py:", "declares grids ['robot'] but returned []"],
        ),
        # Randomness from outside the given rng.
        (
            "distance = float(np.linalg.norm(g0 - g1))",
            "distance = float(np.linalg.norm(g0 - g1)) + np.random.rand()",
            "determinism",
            ["draw every random number from the rng"],
        ),
        # A crash, blamed on the plugin.
        (
            "        if self.params.delay:",
            "        if self.params.delay or True:\n            raise KeyError('speed')\n        if self.params.delay:",
            "plugin_error",
            ["task plugin ToyTask raised KeyError"],
        ),
    ],
)
def test_each_broken_promise_is_a_finding(toy_spec, tmp_path, old, new, check, words):
    report = check_spec(broken_toy(toy_spec, tmp_path, old, new))
    assert not report.ok
    assert check in {f.check for f in report.findings}
    text = "\n".join(map(str, report.findings))
    for word in words:
        assert word in text


def test_grid_shapes_are_checked_per_grid(toy_spec, tmp_path):
    spec = broken_toy(
        toy_spec,
        tmp_path,
        'trajectories={"robot": path},',
        'trajectories={"robot": path}, grids={"robot": np.ones((16, 16)) / 256},',
    )
    plugins = tmp_path / "toy_plugins.py"
    plugins.write_text(
        plugins.read_text().replace("grids: ClassVar[dict[str, tuple[int, int]]] = {}", 'grids = {"robot": (32, 32)}')
    )
    report = check_spec(spec)
    assert any("grid 'robot' has shape (16, 16), declared (32, 32)" in f.message for f in report.findings)


def test_a_finding_of_every_scenario_is_printed_once_with_all_of_them(toy_spec, tmp_path):
    report = check_spec(broken_toy(toy_spec, tmp_path, '"human_variation": variation,', ""), scenarios=2)
    assert len(report.findings) == 1
    assert report.findings[0].scenario == "nominal scenario, random scenario 1, random scenario 2"


def test_findings_exit_2_and_a_spec_that_does_not_compile_too(toy_spec, tmp_path):
    spec = broken_toy(toy_spec, tmp_path, '"human_variation": variation,', "")
    result = runner.invoke(app, ["check", str(spec)])
    assert result.exit_code == 2 and "[metric_error] nominal scenario" in result.output
    result = runner.invoke(app, ["check", str(toy_spec("bind: task.g1x", "bind: task.g9x"))])
    assert result.exit_code == 2 and "does not compile" in result.output and "no parameter 'g9x'" in result.output


def test_an_objective_outside_its_range_is_noted(toy_spec):
    report = check_spec(toy_spec("range: [0, 10]", "range: [0, 1]"))
    assert report.ok  # a note, not a finding: the search still works
    assert any("outside objective.range [0, 1]" in note for note in report.notes)
    assert not any("outside objective.range" in note for note in check_spec(toy_spec()).notes)
