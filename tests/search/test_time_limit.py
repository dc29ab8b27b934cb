"""``--time-limit``: a search stops at its limit, loses nothing, and resumes with a new one."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hritest import search as qd
from hritest.cli import app
from hritest.cli.app import duration
from hritest.rundir import RunDirectory

runner = CliRunner()
TWO = qd.Backend(workers=2, timeout=20)
DELAY = 0.02  # seconds each toy evaluation sleeps: a floor under its cost, however fast the machine


def slow_toy(toy_spec) -> Path:
    return toy_spec("time_limit: 10.0\n", f"time_limit: 10.0\n  params: {{delay: {DELAY}}}\n")


def most_in(seconds: float) -> int:
    """The most evaluations 2 workers can finish in ``seconds``, plus those started at the limit."""
    return int(2 * seconds / DELAY) + 2 * 2


def assert_whole(run: Path) -> int:
    """The run's evaluations are 0..n-1, each once, and its summaries count all of them; returns n."""
    indices = sorted(r.index for r in RunDirectory.open(run).evaluations())
    assert indices == list(range(len(indices)))
    progress = np.loadtxt(run / "progress.csv", delimiter=",", skiprows=1, usecols=(0, 2), ndmin=2)
    assert progress[-1, 0] == len(indices)  # the last batch, cut short by the limit, is told
    assert np.all(np.diff(progress[:, 1]) > 0)  # wall time, accumulated over sessions
    return len(indices)


# The limit counts from the call, start-up included (workers, torch for SAS): 3 and 6 s left a loaded
# 2-core machine no time to tell a batch.
LIMIT = 10.0


@pytest.mark.parametrize("algorithm", ["random", "sas"])
def test_a_time_limit_alone_stops_the_search_in_time_and_loses_nothing(toy_spec, tmp_path, algorithm):
    run = tmp_path / "run"
    found = qd.start(
        spec_file=slow_toy(toy_spec),
        out=run,
        algorithm=algorithm,
        time_limit=LIMIT,
        seed=1,
        backend=TWO,
        surrogate=qd.SurrogateOptions(inner_iterations=20, device="cpu"),
    )
    meta = json.loads((run / "run.json").read_text())
    assert meta["budget"] is None and meta["time_limit"] == LIMIT and meta["stopped"] == "time limit"
    assert not found.done
    evaluated = assert_whole(run)
    assert 0 < evaluated <= most_in(LIMIT)
    # A batch cut short stays pending (a resume finishes it); what it evaluated is in the summaries.
    assert found.state.evaluations <= evaluated <= found.state.known


def test_resumed_with_new_limits_a_run_ends_as_the_run_that_never_stopped(toy_spec, tmp_path):
    spec, run, whole = slow_toy(toy_spec), tmp_path / "run", tmp_path / "whole"
    args = ["--algorithm", "random", "--seed", "2", "--budget", "300", "--workers", "2", "--quiet"]
    first = runner.invoke(app, ["search", str(spec), "--out", str(run), "--time-limit", "1.5s", *args])
    assert first.exit_code in (0, 1), first.output
    before = assert_whole(run)
    assert json.loads((run / "run.json").read_text())["stopped"] == "time limit"

    resume = ["search", "--resume", str(run), "--workers", "2", "--quiet", "--time-limit"]
    again = runner.invoke(app, [*resume, "3"])
    assert again.exit_code in (0, 1), again.output
    after = assert_whole(run)
    assert before < after <= before + most_in(3.0)
    assert json.loads((run / "run.json").read_text())["time_limit"] == 3.0

    last = runner.invoke(app, [*resume, "10m"])
    assert last.exit_code in (0, 1), last.output
    assert assert_whole(run) == 300
    assert json.loads((run / "run.json").read_text())["stopped"] == "budget"
    straight = runner.invoke(app, ["search", str(spec), "--out", str(whole), *args])
    assert straight.exit_code in (0, 1), straight.output
    assert (run / "archive.csv").read_text() == (whole / "archive.csv").read_text()


@pytest.mark.parametrize(("text", "seconds"), [("90", 90), ("90s", 90), ("15m", 900), ("2h", 7200), ("1.5H", 5400)])
def test_durations(text, seconds):
    assert duration(text) == seconds


@pytest.mark.parametrize("text", ["0", "-5m", "5x", "m", "nan", "inf"])
def test_a_bad_time_limit_exits_2_and_writes_nothing(toy_spec, tmp_path, text):
    result = runner.invoke(app, ["search", str(toy_spec()), "--out", str(tmp_path / "run"), "--time-limit", text])
    assert result.exit_code == 2 and "--time-limit" in result.output, result.output
    assert not (tmp_path / "run").exists()
