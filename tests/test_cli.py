"""The command line: exit codes and what a user reads."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

import hritest
from hritest.cli import ExitCode, app
from hritest.cli.runs import Progress

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


def test_validate_names_every_invalid_plugin_param_in_one_run(toy_spec):
    spec = toy_spec("  time_limit: 10.0\n", "  time_limit: 10.0\n  params: {scale: .nan, fault_above: .inf}\n")
    result = runner.invoke(app, ["validate", str(spec)])
    assert result.exit_code == 2, result.output
    assert "task.params.scale: expected a finite number, not nan" in result.output
    assert "task.params.fault_above: expected a finite number, not inf" in result.output


def test_show_prints_the_layout(toy_spec):
    result = runner.invoke(app, ["show", str(toy_spec())])
    assert result.exit_code == 0, result.output
    for text in ("theta: 7 components", "noise[2]", "human.noise", "16 x 16 cells", "failure when objective >= 8"):
        assert text in result.output


def test_input_errors_exit_2(tmp_path):
    assert runner.invoke(app, ["show", str(tmp_path / "missing.yaml")]).exit_code == 2
    assert runner.invoke(app, ["show"]).exit_code == 2
    assert runner.invoke(app, ["no-such-command"]).exit_code == 2


FAULTY = "time_limit: 10.0\n", "time_limit: 10.0\n  params: {fault: raise, fault_above: -1}\n"  # every scenario
NOMINAL = "0.6,0.05,0.6,0.1,0.01,0,0"


def test_exit_codes_are_distinct_and_documented():
    codes = [code.value for code in ExitCode]
    assert len(set(codes)) == len(codes)
    readme = (Path(__file__).parent.parent / "README.md").read_text()
    for code in ExitCode:
        assert f"**{code.value}**" in readme, code


def test_simulate_exits_3_when_the_scenario_cannot_be_evaluated(toy_spec):
    assert runner.invoke(app, ["simulate", str(toy_spec()), "--theta", NOMINAL]).exit_code in (0, 1)
    result = runner.invoke(app, ["simulate", str(toy_spec(*FAULTY)), "--theta", NOMINAL])
    assert result.exit_code == ExitCode.INCOMPLETE == 3, result.output
    assert "plugin_error" in result.output and "toy plugin exploded" in result.output


@pytest.mark.parametrize("fault", ["sys_exit", "interrupt"])
def test_a_plugin_that_exits_or_interrupts_is_a_plugin_error(toy_spec, fault):
    spec = toy_spec(FAULTY[0], FAULTY[1].replace("raise", fault))
    result = runner.invoke(app, ["simulate", str(spec), "--theta", NOMINAL, "--json"])
    assert result.exit_code == 3, result.output
    assert json.loads(result.stdout)["status"] == "plugin_error"


def test_a_search_where_nothing_completes_exits_3(toy_spec, tmp_path):
    result = runner.invoke(
        app,
        ["search", str(toy_spec(*FAULTY)), "--out", str(tmp_path / "run"), "--budget", "20", "--workers", "1", "-q"],
    )
    assert result.exit_code == 3, result.output
    assert "no evaluation completed" in result.output


def test_a_bug_in_hritest_exits_4_with_its_traceback_in_a_file(toy_spec, monkeypatch):
    def broken(*args, **kwargs):
        raise RuntimeError("an internal inconsistency")

    monkeypatch.setattr("hritest.evaluate.evaluate", broken)
    result = runner.invoke(app, ["simulate", str(toy_spec()), "--theta", NOMINAL])
    assert result.exit_code == ExitCode.BUG == 4
    assert "bug in hritest" in result.output and "Traceback" not in result.output
    log = Path(re.search(r"the traceback is in (\S+?\.log)", result.output)[1])
    assert "RuntimeError: an internal inconsistency" in log.read_text() and "Traceback" in log.read_text()
    log.unlink()


def test_a_bug_during_a_search_writes_its_traceback_into_the_run(toy_spec, tmp_path, monkeypatch):
    def broken(self, search, records, solutions):
        raise ValueError("a scheduler that cannot take its batch")

    monkeypatch.setattr("hritest.search.proposers.ModelFree.tell", broken)
    run = tmp_path / "run"
    args = ["search", str(toy_spec()), "--out", str(run), "--budget", "20", "--algorithm", "random", "-q"]
    result = runner.invoke(app, [*args, "--workers", "1"])
    assert result.exit_code == 4, result.output
    assert f"the traceback is in {run / 'error.log'}" in " ".join(result.output.split())
    assert "ValueError: a scheduler that cannot take its batch" in (run / "error.log").read_text()
    assert "Traceback" not in result.output


def test_a_plugin_that_exits_at_import_is_an_invalid_spec(toy_spec, tmp_path):
    good = toy_spec()
    bad_dir = tmp_path / "bad"
    bad_dir.mkdir()
    (bad_dir / "toy_plugins.py").write_text((tmp_path / "toy_plugins.py").read_text() + "\nimport sys\nsys.exit(0)\n")
    bad = bad_dir / "spec.yaml"
    bad.write_text(good.read_text())
    result = runner.invoke(app, ["validate", str(bad), str(good)])
    assert result.exit_code == 2, result.output
    assert f"invalid {bad}" in result.output and "called sys.exit(0) while being imported" in result.output
    assert f"ok {good}" in result.output  # the specs after it are still checked


def test_sas_with_a_budget_its_surrogate_never_sees_is_refused(toy_spec, tmp_path):
    run = tmp_path / "run"
    result = runner.invoke(app, ["search", str(toy_spec()), "--algorithm", "sas", "--budget", "100", "--out", str(run)])
    assert result.exit_code == 2, result.output
    text = " ".join(result.output.split())
    assert "budget of 100" in text and "first 100 (search.surrogate.initial_evaluations)" in text
    assert not run.exists()


def test_without_a_terminal_a_search_prints_plain_progress_lines(toy_spec, tmp_path):
    args = ["search", str(toy_spec()), "--out", str(tmp_path / "run"), "--budget", "60", "--workers", "1"]
    result = runner.invoke(app, [*args, "--algorithm", "random", "--seed", "3"])
    assert result.exit_code in (0, 1), result.output
    lines = [line for line in result.stderr.splitlines() if line.startswith("search: ")]
    assert len(lines) >= 2  # when it starts and when it ends
    assert all("evaluations/s" in line and "failures" in line and "did not complete" in line for line in lines)
    assert lines[-1].startswith("search: 60/60 evaluations, QD-score ")
    assert "writing the report" in result.stderr
    assert "\x1b[" not in result.stderr  # no bar, no cursor movements

    quiet = runner.invoke(app, [*args[:3], str(tmp_path / "quiet"), *args[4:], "--algorithm", "random", "-q"])
    assert quiet.exit_code in (0, 1) and "search: " not in quiet.stderr


@pytest.mark.parametrize("width", [50, 80, 200])
def test_on_a_terminal_the_progress_bar_fits_its_width(monkeypatch, width):
    from rich.console import Console

    from hritest.search import Snapshot
    from hritest.search.archives import Summary

    monkeypatch.setattr("hritest.cli.runs.err", Console(force_terminal=True, width=width, file=io.StringIO()))
    screen = Console(force_terminal=True, width=width, record=True, file=io.StringIO())
    summary = Summary(qd_score=123456.7, normalized_qd_score=0.5, coverage=0.4321, best=9.87, elites=42)
    with Progress(quiet=False) as progress:
        progress(Snapshot(evaluations=1234, budget=100000, summary=summary, failures=56, failed=7))
        screen.print(progress.bar.get_renderable())
    [line] = screen.export_text().splitlines()  # one line, not wrapped
    assert len(line) <= width
    assert line.startswith("search ") and "1234/100000" in line and "QD-score" in line


@pytest.mark.parametrize(
    "theta", ["0.6,0.05,,0.6,0.1,0.01,0,0", "nan,0.05,0.6,0.1,0.01,0,0", "0.6,0.05,0.6,0.1,0.01,0,inf", "0.6,x"]
)
@pytest.mark.parametrize("command", ["simulate", "repair"])
def test_a_bad_theta_is_an_input_error(toy_spec, command, theta):
    result = runner.invoke(app, [command, str(toy_spec()), "--theta", theta], env={"COLUMNS": "500"})
    assert result.exit_code == 2 and "--theta" in result.output, result.output
    assert "Traceback" not in result.output


def test_what_a_plugin_prints_does_not_break_simulate_json(toy_spec):
    spec = toy_spec("time_limit: 10.0\n", "time_limit: 10.0\n  params: {chatty: true}\n")
    result = runner.invoke(app, ["simulate", str(spec), "--theta", NOMINAL, "--json"])
    assert result.exit_code in (0, 1), result.output
    assert json.loads(result.stdout)["status"] == "ok"
    assert "toy task: running" in result.stderr


def test_replay_exits_3_when_the_scenario_cannot_be_evaluated(toy_spec, tmp_path):
    args = ["replay", str(toy_spec(*FAULTY)), "--theta", NOMINAL, "--out", str(tmp_path / "r.rrd")]
    result = runner.invoke(app, args)
    assert result.exit_code == 3, result.output
