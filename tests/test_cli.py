"""The command line: exit codes and what a user reads."""

from __future__ import annotations

from typer.testing import CliRunner

import hritest
from hritest.cli import app

runner = CliRunner()


def test_version():
    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0
    assert result.output.strip() == f"hritest {hritest.__version__}"


def test_validate_ok_and_bad(toy_spec, tmp_path):
    good = toy_spec()
    result = runner.invoke(app, ["validate", str(good)])
    assert result.exit_code == 0, result.output
    assert f"ok {good}" in result.output

    bad = tmp_path / "bad.yaml"
    bad.write_text(good.read_text().replace("cells: 16}\n  - {name: variation", "cells: -1}\n  - {name: variation"))
    result = runner.invoke(app, ["validate", str(good), str(bad)])
    assert result.exit_code == 2
    assert f"invalid {bad}" in result.output
    assert f"{bad}:" in result.output and "measures[0].cells" in result.output


def test_show_prints_the_layout(toy_spec):
    result = runner.invoke(app, ["show", str(toy_spec())])
    assert result.exit_code == 0, result.output
    for text in ("theta: 7 components", "noise[2]", "human.noise", "16 x 16 cells", "failure when objective >= 8"):
        assert text in result.output


def test_input_errors_exit_2(tmp_path):
    assert runner.invoke(app, ["show", str(tmp_path / "missing.yaml")]).exit_code == 2
    assert runner.invoke(app, ["show"]).exit_code == 2
    assert runner.invoke(app, ["no-such-command"]).exit_code == 2
