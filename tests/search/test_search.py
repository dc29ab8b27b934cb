"""Searches end to end on the analytic toy domain: real pyribs, real process pools, real files."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import psutil
import pytest
import yaml
from typer.testing import CliRunner

from hritest import search as qd
from hritest.cli import app
from hritest.interrupt import Interrupted
from hritest.report import load_run
from hritest.rundir import RunDirectory, RunDirectoryError, unpack
from hritest.search.state import load_state

FIXTURES = Path(__file__).parents[1] / "fixtures"

runner = CliRunner()
TWO = qd.Backend(workers=2, timeout=20)


def elites(run: Path) -> list[dict]:
    return (run / "archive.csv").read_text().splitlines()


@pytest.mark.parametrize("algorithm", ["random", "map_elites", "cma_mae"])
def test_each_algorithm_fills_both_archives_and_the_run_directory(toy_spec, tmp_path, algorithm):
    found = qd.start(spec_file=toy_spec(), out=tmp_path / "run", algorithm=algorithm, budget=250, seed=3, backend=TWO)
    run = tmp_path / "run"
    for name in (
        "spec.yaml",
        "run.json",
        "evaluations.jsonl",
        "occupancy.f32",
        "checkpoint.pkl",
        "progress.csv",
        "archive.csv",
        "failures.yaml",
    ):
        assert (run / name).is_file(), name
    records = RunDirectory.open(run).evaluations()
    assert sorted(r.index for r in records) == list(range(250))  # exactly the budget, none twice
    assert all(r.status == "ok" for r in records)
    assert found.state.result.stats.num_elites > 1
    # The result archive holds raw objectives; the regularised ones only differ by the repair cost.
    for r in records:
        assert r.search_objective == pytest.approx(r.objective - r.repair_cost)
    failures = yaml.safe_load((run / "failures.yaml").read_text())["failures"]
    assert all(f["objective"] >= 8 for f in failures)
    assert len(failures) == sum(
        r.failure for r in records if r.index in {int(i) for i in found.state.result.data("evaluation")}
    )


def test_same_spec_and_seed_give_the_same_result_archive(toy_spec, tmp_path):
    spec = toy_spec()
    a = qd.start(spec_file=spec, out=tmp_path / "a", budget=400, seed=7, backend=TWO)
    b = qd.start(spec_file=spec, out=tmp_path / "b", budget=400, seed=7, backend=qd.Backend(workers=1))
    qd.start(spec_file=spec, out=tmp_path / "c", budget=400, seed=8, backend=TWO)
    assert elites(tmp_path / "a") == elites(tmp_path / "b")
    assert elites(tmp_path / "a") != elites(tmp_path / "c")
    assert a.state.result.stats.qd_score == b.state.result.stats.qd_score


@pytest.mark.parametrize(
    ("fault", "status"),
    [
        ("raise", "plugin_error"),
        ("nan", "nan"),
        ("exit", "crashed"),  # os._exit: the worker dies
        ("hang", "timeout"),
        ("sys_exit", "plugin_error"),  # SystemExit is the scenario's, not the search's
        ("interrupt", "plugin_error"),  # so is a KeyboardInterrupt the plugin raises
    ],
)
def test_a_misbehaving_plugin_fails_its_scenarios_only(toy_spec, tmp_path, fault, status):
    spec = toy_spec("time_limit: 10.0\n", f"time_limit: 10.0\n  params: {{fault: {fault}, fault_above: 0.045}}\n")
    found = qd.start(
        spec_file=spec,
        out=tmp_path / "run",
        algorithm="random",
        budget=60,
        seed=1,
        backend=qd.Backend(workers=2, timeout=1.0),
    )
    records = RunDirectory.open(tmp_path / "run").evaluations()
    assert sorted(r.index for r in records) == list(range(60))
    bad = [r for r in records if r.theta[4] > 0.045]
    good = [r for r in records if r.theta[4] <= 0.045]
    assert bad and good
    assert {r.status for r in bad} == {status}
    assert all(r.status == "ok" for r in good)  # neighbours of a crash are not blamed
    assert all("retry" in r.message for r in bad)
    if fault == "raise":
        assert "task plugin ToyTask raised RuntimeError: toy plugin exploded" in bad[0].message
    elites_ = {int(i) for i in found.state.result.data("evaluation")}
    assert elites_.isdisjoint(r.index for r in bad)


def start_in_background(
    spec: Path, out: Path, *, until_lines: int, stderr: int = subprocess.DEVNULL
) -> subprocess.Popen:
    """A 700-evaluation search in its own process, returned once ``until_lines`` evaluations are in."""
    command = [
        sys.executable,
        "-m",
        "hritest.cli",
        "search",
        str(spec),
        "--budget",
        "700",
        "--seed",
        "5",
        "--workers",
        "2",
        "--quiet",
        "--out",
        str(out),
    ]
    process = subprocess.Popen(command, start_new_session=True, stdout=subprocess.DEVNULL, stderr=stderr)
    lines = out / "evaluations.jsonl"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if lines.exists() and len(lines.read_text().splitlines()) > until_lines:
            break
        time.sleep(0.05)
    return process


def kill(process: subprocess.Popen) -> None:
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()


def resume_to_the_end(run: Path) -> list[dict]:
    result = runner.invoke(app, ["search", "--resume", str(run), "--workers", "2", "--quiet"])
    assert result.exit_code in (0, 1) and isinstance(result.exception, SystemExit | None), result.output
    after = RunDirectory.open(run).evaluations()
    assert sorted(r.index for r in after) == list(range(700))
    progress = np.loadtxt(run / "progress.csv", delimiter=",", skiprows=1, usecols=0)
    assert progress[-1] == 700
    return after


def test_a_killed_run_resumes_to_the_same_state(toy_spec, tmp_path):
    spec = toy_spec("time_limit: 10.0\n", "time_limit: 10.0\n  params: {delay: 0.01}\n")
    qd.start(spec_file=spec, out=tmp_path / "whole", budget=700, seed=5, backend=TWO)

    killed = tmp_path / "killed"
    kill(start_in_background(spec, killed, until_lines=350))  # in the middle of its second batch
    before = RunDirectory.open(killed).evaluations()
    assert 350 < len(before) < 700

    after = resume_to_the_end(killed)
    done_before = {r.index: r for r in before}
    redone = [r for r in after if r.index in done_before and r != done_before[r.index]]
    assert not redone  # nothing finished before the kill was evaluated again
    assert elites(killed) == elites(tmp_path / "whole")


@pytest.mark.parametrize(
    ("signum", "code"),
    [
        (signal.SIGINT, 130),  # Ctrl-C: a terminal sends it to the whole process group
        (signal.SIGTERM, 143),  # kill, a CI runner's cancel: to the search only
        (signal.SIGKILL, -signal.SIGKILL),  # nothing runs in the search, but its workers still die
    ],
    ids=["SIGINT", "SIGTERM", "SIGKILL"],
)
def test_a_stopped_search_leaves_no_process_behind_and_resumes(toy_spec, tmp_path, signum, code):
    spec = toy_spec("time_limit: 10.0\n", "time_limit: 10.0\n  params: {delay: 0.05}\n")
    run = tmp_path / "run"
    process = start_in_background(spec, run, until_lines=20, stderr=subprocess.PIPE)
    workers = psutil.Process(process.pid).children(recursive=True)
    assert len(workers) >= 2  # the pool's (and the pool's resource tracker)
    if signum == signal.SIGINT:
        os.killpg(process.pid, signum)
    else:
        process.send_signal(signum)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == code, stderr.decode()
    if signum != signal.SIGKILL:
        assert f"hritest search --resume {run}" in stderr.decode()
        assert "Traceback" not in stderr.decode()
    assert not [w.pid for w in workers if alive(w)]
    resume_to_the_end(run)


def alive(process: psutil.Process, *, within: float = 10.0) -> bool:
    """Whether ``process`` still runs after up to ``within`` seconds (a killed one takes a moment)."""
    deadline = time.monotonic() + within
    while time.monotonic() < deadline:
        try:
            if process.status() == psutil.STATUS_ZOMBIE:
                return False
        except psutil.NoSuchProcess:
            return False
        time.sleep(0.05)
    return True


def test_a_run_packed_while_it_runs_resumes_elsewhere_to_the_same_state(toy_spec, tmp_path):
    spec = toy_spec("time_limit: 10.0\n", "time_limit: 10.0\n  params: {delay: 0.01}\n")
    qd.start(spec_file=spec, out=tmp_path / "whole", budget=700, seed=5, backend=TWO)

    process = start_in_background(spec, tmp_path / "here" / "run", until_lines=350)
    packed = RunDirectory.open(tmp_path / "here" / "run").pack()  # while it writes
    kill(process)
    archive = tmp_path / "run.tar.xz"
    archive.write_bytes(packed)
    run = unpack(archive, tmp_path / "there")
    assert run.path == tmp_path / "there" / "run"
    assert 350 < len(run.evaluations()) < 700
    resume_to_the_end(run.path)
    assert elites(run.path) == elites(tmp_path / "whole")

    with pytest.raises(RunDirectoryError, match="exists already"):  # never over a run
        unpack(archive, tmp_path / "there")
    archive.write_bytes(packed[: len(packed) // 2])
    with pytest.raises(RunDirectoryError, match="cannot be unpacked"):
        unpack(archive, tmp_path / "elsewhere")
    assert not (tmp_path / "elsewhere" / "run").exists()  # nothing half-unpacked


def test_resume_refuses_bad_run_directories(toy_spec, tmp_path):
    spec = toy_spec()
    assert runner.invoke(app, ["search", "--resume", str(tmp_path / "nothing")]).exit_code == 2
    (tmp_path / "empty").mkdir()
    result = runner.invoke(app, ["search", "--resume", str(tmp_path / "empty")])
    assert result.exit_code == 2 and "not a hritest run directory" in result.output

    qd.start(spec_file=spec, out=tmp_path / "run", budget=20, seed=0, algorithm="random", backend=TWO)
    (tmp_path / "run" / "checkpoint.pkl").write_bytes(b"garbage")
    result = runner.invoke(app, ["search", "--resume", str(tmp_path / "run")])
    assert result.exit_code == 2 and "not signed" in result.output

    qd.start(spec_file=spec, out=tmp_path / "run2", budget=20, seed=0, algorithm="random", backend=TWO)
    spec.write_text(spec.read_text().replace("budget: 500", "budget: 501"))
    before = (tmp_path / "run2" / "evaluations.jsonl").read_text()
    result = runner.invoke(app, ["search", "--resume", str(tmp_path / "run2")])
    assert result.exit_code == 2 and "changed since this run started" in result.output
    assert (tmp_path / "run2" / "evaluations.jsonl").read_text() == before  # nothing written


def test_bad_arguments_exit_2_and_write_nothing(toy_spec, tmp_path):
    spec = toy_spec()
    bad = (
        ["--workers", "0"],
        ["--algorithm", "nope"],
        ["--budget", "0"],
        *(["--timeout", value] for value in ("0", "-1", "nan")),  # none may switch the timeout off
        ["--cluster", "not-an-address"],
    )
    for args in bad:
        result = runner.invoke(app, ["search", str(spec), "--out", str(tmp_path / "run"), *args])
        assert result.exit_code == 2, (args, result.output)
        assert not (tmp_path / "run").exists()
    (tmp_path / "a-file").write_text("mine")
    result = runner.invoke(app, ["search", str(spec), "--out", str(tmp_path / "a-file")], env={"COLUMNS": "500"})
    assert result.exit_code == 2 and "is a file" in result.output
    assert (tmp_path / "a-file").read_text() == "mine"
    result = runner.invoke(
        app, ["search", str(spec), "--out", str(tmp_path / "a-file" / "run")], env={"COLUMNS": "500"}
    )
    assert result.exit_code == 2 and "cannot write the run directory" in result.output  # not a bug (exit 4)
    result = runner.invoke(app, ["search", str(spec), "--cluster", "tcp://127.0.0.1:1", "--out", str(tmp_path / "run")])
    assert result.exit_code == 2 and ("Dask" in result.output or "cannot reach" in result.output)
    assert not (tmp_path / "run").exists()


def test_run_json_records_what_is_needed_to_reproduce(toy_spec, tmp_path):
    qd.start(spec_file=toy_spec(), out=tmp_path / "run", budget=10, seed=2, algorithm="random", backend=TWO)
    meta = json.loads((tmp_path / "run" / "run.json").read_text())
    assert meta["seed"] == 2 and meta["algorithm"] == "random" and meta["budget"] == 10
    assert "inner_iterations" not in meta  # only surrogate runs have an inner loop
    assert {"hritest", "mujoco", "ribs", "numpy"} <= set(meta["versions"])


def test_the_command_line_search_ends_with_a_report_and_exit_1_for_failures(toy_spec, tmp_path):
    result = runner.invoke(
        app, ["search", str(toy_spec()), "--budget", "120", "--workers", "2", "--quiet", "--out", str(tmp_path / "run")]
    )
    assert result.exit_code == 1 and isinstance(result.exception, SystemExit), result.output
    assert "failures" in result.output and (tmp_path / "run" / "report" / "index.html").is_file()
    assert f"report: {tmp_path / 'run' / 'report' / 'index.html'}" in result.output


@pytest.mark.parametrize("algorithm", ["sas", "dsas"])
def test_time_share_cuts_each_outer_iteration_to_what_simulating_a_batch_takes(toy_spec, tmp_path, algorithm):
    """With a share far below what 2,000 inner iterations cost next to a toy batch's simulation,
    every inner loop is cut; with ``time_share: 1`` none is."""
    surrogate = "{initial_evaluations: 30, inner_iterations: %d, inner_stall: null, epochs: 5, time_share: %s}"
    runs = {}
    for share, iterations in (("0.01", 2000), ("1", 20)):
        spec = toy_spec("budget: 500", f"budget: 500\n  surrogate: {surrogate % (iterations, share)}")
        runs[share] = qd.start(
            spec_file=spec, out=tmp_path / share, algorithm=algorithm, budget=90, seed=0, backend=TWO
        )
    cut, whole = (runs[share].state for share in ("0.01", "1"))
    assert len(cut.proposer.fits) >= 2 and len(whole.proposer.fits) >= 2
    rows = [SimpleNamespace(evaluations=0, wall_time=0.0), *cut.progress]
    largest = 30  # the initial batch: a fit's share is of a batch as large as the largest before it
    for k, fit in enumerate(cut.proposer.fits):  # fit k follows batch k
        simulated = rows[k + 1].wall_time - rows[k].wall_time - rows[k + 1].propose_seconds
        per_evaluation = simulated / (rows[k + 1].evaluations - rows[k].evaluations)
        assert 1 <= fit["inner_iterations"] < 2000
        assert fit["seconds_allowed"] == pytest.approx(per_evaluation * largest * 0.01 / 0.99, abs=1e-3)
        largest = max(largest, fit["proposed"])
    assert all(f["inner_iterations"] == 20 and f["seconds_allowed"] is None for f in whole.proposer.fits)
    assert json.loads((tmp_path / "1" / "run.json").read_text())["time_share"] == 1
    stored = load_run(tmp_path / "0.01").surrogate["fits"]  # surrogate.json
    assert [f["inner_iterations"] for f in stored] == [f["inner_iterations"] for f in cut.proposer.fits]


@pytest.mark.parametrize("algorithm", ["sas", "dsas"])
def test_sas_and_dsas_search_a_task_without_grids_and_resume(toy_spec, tmp_path, algorithm):
    """The toy task declares no occupancy grids: the surrogate learns from theta alone."""
    spec = toy_spec(
        "budget: 500",
        "budget: 500\n  surrogate: {initial_evaluations: 30, inner_iterations: 20, epochs: 5, batch_size: 16}",
    )
    found = qd.start(
        spec_file=spec,
        out=tmp_path / "run",
        algorithm=algorithm,
        budget=60,
        seed=0,
        backend=TWO,
        surrogate=qd.SurrogateOptions(device="cpu"),
    )
    assert found.domain.grids == {}
    proposer = found.state.proposer
    assert proposer.surrogate.occupancy is None and proposer.outer >= 2
    assert all(np.isnan(f["occupancy_loss"]) and np.isfinite(f["predictor_loss"]) for f in proposer.fits)
    assert np.isfinite(proposer.accuracy(found.domain)["objective_mae"])
    assert (tmp_path / "run" / "occupancy.f32").stat().st_size == 0

    run = RunDirectory.open(tmp_path / "run")
    run.save_checkpoint(replace(load_state(run), budget=80))
    again = qd.resume(run_path=tmp_path / "run", backend=TWO)
    assert again.state.evaluations == 80
    assert sorted(r.index for r in RunDirectory.open(tmp_path / "run").evaluations()) == list(range(80))
    assert again.state.proposer.outer > proposer.outer

    from hritest.report import write_report

    assert np.isnan(load_run(tmp_path / "run").surrogate["fits"][0]["occupancy_loss"])  # surrogate.json
    assert write_report(tmp_path / "run", recordings=0).is_file()


def pipelined_spec(toy_spec, *, delay: float, inner_iterations: int = 20) -> Path:
    """The toy domain searched by a pipelined SAS, each episode sleeping ``delay`` seconds. With the
    paper's training, a fit's samples say which batches it had been told."""
    text = (FIXTURES / "toy.yaml").read_text()
    text = text.replace("time_limit: 10.0\n", f"time_limit: 10.0\n  params: {{delay: {delay}}}\n")
    text = text.replace(
        "algorithm: cma_mae",
        "algorithm: sas\n  surrogate: {initial_evaluations: 30, inner_iterations: "
        f"{inner_iterations}, epochs: 5, batch_size: 16, pipeline: true, training: paper, time_share: 1}}",
    )
    return toy_spec(text=text)


def test_a_pipelined_sas_asks_each_batch_while_the_last_simulates_and_resumes_to_the_same_run(toy_spec, tmp_path):
    spec = pipelined_spec(toy_spec, delay=0.01)
    whole = qd.start(spec_file=spec, out=tmp_path / "whole", budget=700, seed=5, backend=TWO)
    told = [int(row.evaluations) for row in whole.state.progress]  # after each batch
    assert len(told) >= 4 and told[0] == 30
    # Batch 2 is asked once the initial batch is told; from then on, batch m is asked while m - 1
    # simulates, so its surrogate learned from the batches before m - 1 (without the pipeline:
    # told[:-1]). The last batch, which ends the budget, has nothing to ask ahead of.
    assert [fit["samples"] for fit in whole.state.proposer.fits] == [30, *told[:-2]]
    assert whole.state.ahead is None

    killed = tmp_path / "killed"
    kill(start_in_background(spec, killed, until_lines=told[1] + 10))  # batch 3 simulating, batch 4 asked
    assert told[1] + 10 < len(RunDirectory.open(killed).evaluations()) < 700
    resume_to_the_end(killed)
    assert elites(killed) == elites(tmp_path / "whole")


def test_an_interrupt_stops_a_pipelined_ask_and_leaves_the_batch_in_flight_resumable(toy_spec, tmp_path):
    """Ctrl-C while the next batch is asked on its thread: the ask stops with the search (its
    inner loop would go on for seconds), and the checkpoint holds the batch in flight only."""
    spec = pipelined_spec(toy_spec, delay=0.05, inner_iterations=300)

    def interrupt_once_asking_ahead(snapshot: qd.Snapshot) -> None:
        if snapshot.phase.startswith("simulating + "):
            raise KeyboardInterrupt

    with pytest.raises(Interrupted) as stopped:
        qd.start(
            spec_file=spec, out=tmp_path / "run", budget=700, seed=5, backend=TWO, progress=interrupt_once_asking_ahead
        )
    assert stopped.value.signum == signal.SIGINT
    assert not [t for t in threading.enumerate() if t.name == "hritest-ask-ahead" and t.is_alive()]
    state = load_state(RunDirectory.open(tmp_path / "run"))
    assert state.evaluations == 30 and state.pending is not None and state.ahead is None
