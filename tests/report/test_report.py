"""Reports of real (toy-domain) searches: files, numbers, embedded figures, comparison, bad input."""

from __future__ import annotations

import base64
import csv
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from hritest import search as qd
from hritest.cli import app
from hritest.recording import recorded_entities
from hritest.records import Clause, EvaluationRecord, Status, rank_failures, worst_of_each_clause
from hritest.report import chosen_failures, cluster_failures, load_run, worst_failures, write_report
from hritest.rundir import RunDirectory

FIXTURES = Path(__file__).parent.parent / "fixtures"
runner = CliRunner()


def toy_run(folder: Path, *, failure: str = "objective >= 8", budget: int = 150, seed: int = 1) -> Path:
    """A finished random search of the toy domain in ``folder/run``."""
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copy(FIXTURES / "toy_plugins.py", folder / "toy_plugins.py")
    spec = folder / "toy.yaml"
    spec.write_text((FIXTURES / "toy.yaml").read_text().replace("failure: objective >= 8", f"failure: {failure}"))
    qd.start(
        spec_file=spec, out=folder / "run", algorithm="random", budget=budget, seed=seed, backend=qd.Backend(workers=1)
    )
    return folder / "run"


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    return toy_run(tmp_path_factory.mktemp("toy"))


@pytest.fixture(scope="module")
def calm_run(tmp_path_factory) -> Path:
    """A run whose failure condition no scenario meets."""
    return toy_run(tmp_path_factory.mktemp("calm"), failure="objective >= 100", budget=100, seed=2)


@pytest.fixture(scope="module")
def reported(run) -> Path:
    return write_report(run, recordings=2)


def failures_of(run: Path) -> list[dict]:
    return yaml.safe_load((run / "failures.yaml").read_text())["failures"]


def test_report_files_exist_with_embedded_figures(run, reported):
    assert reported == run / "report" / "index.html"
    for name in ("index.html", "summary.md", "archive.png", "qd_score.png"):
        assert (run / "report" / name).is_file(), name
    page = reported.read_text()
    images = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page)
    assert len(images) == 2  # the archive heatmap and the QD-score curves
    assert all(base64.b64decode(data).startswith(b"\x89PNG\r\n\x1a\n") for data in images)
    assert 'src="http' not in page and "<script" not in page  # self-contained, opens from disk
    assert "![result archive of run](archive.png)" in (run / "report" / "summary.md").read_text()


def test_report_shows_the_numbers_of_progress_csv(run, reported):
    page = reported.read_text()
    with open(run / "progress.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    last = rows[-1]
    assert f"{float(last['qd_score']):.2f}" in page
    assert f"{float(last['normalized_qd_score']):.4f}" in page
    assert f"{float(last['coverage']):.2%}" in page
    assert f"{float(last['wall_time']):.1f} s" in page
    assert f"{int(last['evaluations'])} of a budget of 150" in page
    for row in rows:  # the full log, folded away
        assert f'<td class="num">{int(row["evaluations"])}</td>' in page
        assert f'<td class="num">{float(row["qd_score"]):.6g}</td>' in page
    assert "150 ok" in page  # the statuses


def test_a_report_a_replay_and_a_promotion_keep_only_the_records_they_show(run, tmp_path, monkeypatch):
    # Holding every record, the report of a million teleoperation evaluations took 3.3 GB: they
    # read evaluations.jsonl one record at a time, keeping the elites and the reported failures.
    from hritest.promote import promote
    from hritest.replay import stored_failure

    def every_record(self):
        raise AssertionError("read every record of the run into memory")

    monkeypatch.setattr(RunDirectory, "evaluations", every_record)
    data = load_run(run)
    assert data.evaluated == 150 and data.statuses == {"ok": 150}
    ids = [f["id"] for f in failures_of(run)]
    assert [r.index for r in data.failures] == ids and len(data.elites) > len(ids) > 0
    assert stored_failure(RunDirectory.open(run), ids[-1]).index == ids[-1]
    assert [p.evaluation for p in promote(run, corpus=tmp_path / "corpus", top=2)] == ids[:2]


def test_report_lists_every_failure_and_links_recordings(run, reported):
    page = reported.read_text()
    failures = failures_of(run)
    assert failures, "the toy search should find failures"
    assert f"{len(failures)} elites meet" in page
    for failure in failures:
        assert f'<td class="num">{failure["id"]}</td>' in page
    recorded = sorted((run / "recordings").glob("*.rrd"))
    # The 2 worst, the worst of each clause, and each kind's representative.
    data = load_run(run)
    expected = {r.index for r in worst_failures(data.failures, 2)}
    expected |= {r.index for r in worst_of_each_clause(data.failures).values()}
    expected |= {c.representative.index for c in data.clusters}
    assert {int(p.stem) for p in recorded} == expected
    for path in recorded:
        assert f'href="../recordings/{path.name}"' in page
    assert "each re-simulation reproduced its stored outcome" in page


def failure(index: int, objective: float, measures: list[float], fired: tuple[str, ...] = ()) -> EvaluationRecord:
    """A failure's record as a search writes it, with the clauses in ``fired`` held."""
    return EvaluationRecord(
        index=index, batch=1, status=Status.OK, failure=True, objective=objective, search_objective=objective,
        measures=tuple(measures), repair_cost=0.0, regions={}, theta=(0.0,), theta_repaired=(0.0,), metrics={},
        seed=index, seconds=0.0, clauses=tuple(Clause(text=c, holds=True) for c in fired),
    )  # fmt: skip


def test_failures_that_behave_apart_are_kinds_each_represented_by_its_worst():
    # Two kinds: low goal distance with a long completion, and a high one tripping a safety clause.
    rng = np.random.default_rng(0)
    slow = [failure(i, 9.0 + rng.random(), [0.02 + 0.01 * rng.random(), 0.01], ("objective >= 8",)) for i in range(8)]
    unsafe = [failure(20 + i, 3.0 + rng.random(), [0.28 + 0.01 * rng.random(), 0.08], ("gap < 0.1",)) for i in range(5)]
    clusters = cluster_failures(slow + unsafe, measure_names=["distance", "variation"], ranges=[(0, 0.32), (0, 0.087)])
    assert [sorted(r.index for r in c.members) for c in clusters] == [list(range(8)), list(range(20, 25))]
    assert clusters[0].representative == rank_failures(slow)[0]
    assert set(clusters[0].traits) == {
        "variation low: 0.115 of its range (others 0.92)",
        "'objective >= 8' holds in 100% (others 0%)",
    }
    assert "'gap < 0.1' holds in 100% (others 0%)" in clusters[1].traits
    # Failures that are all alike are one kind, with nothing setting it apart.
    [alike] = cluster_failures(slow, measure_names=["distance", "variation"], ranges=[(0, 0.32), (0, 0.087)])
    assert len(alike.members) == 8 and alike.traits == ()


def test_ties_rank_by_index_and_every_clause_that_fired_is_chosen_for_recording():
    failures = [
        failure(7, 10.0, [0.1, 0.01], ("objective >= 10",)),
        failure(3, 10.0, [0.1, 0.01], ("objective >= 10",)),
        failure(5, 10.0, [0.1, 0.01], ("objective >= 10",)),
        failure(9, 2.0, [0.1, 0.01], ("approach < 0.3",)),  # a safety failure, far from the worst objective
    ]
    assert [r.index for r in worst_failures(failures, 4)] == [3, 5, 7, 9]
    chosen = chosen_failures(failures, [], 1)
    assert [r.index for r in chosen] == [3, 9]


def test_a_run_without_failures_says_so(calm_run):
    result = runner.invoke(app, ["report", str(calm_run)])
    assert result.exit_code == 0, result.output
    page = (calm_run / "report" / "index.html").read_text()
    assert "No failures: no elite of the result archive meets the failure condition" in page
    assert "objective &gt;= 100" in page
    assert not (calm_run / "recordings").exists()
    assert "No failures" in (calm_run / "report" / "summary.md").read_text()


def test_comparing_two_runs(run, calm_run, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = runner.invoke(app, ["report", str(run), str(calm_run)])
    assert result.exit_code == 0, result.output
    page = (tmp_path / "report-compare" / "index.html").read_text()
    assert "comparison of 2 runs" in page
    assert page.count("data:image/png;base64,") == 2  # shared curves, archives side by side
    for folder in (run, calm_run):
        with open(folder / "progress.csv", newline="") as handle:
            last = list(csv.DictReader(handle))[-1]
        assert f"{float(last['qd_score']):.2f}" in page
    assert "different specs" in page  # the two toy specs differ in their failure condition
    assert (tmp_path / "report-compare" / "summary.md").is_file()

    result = runner.invoke(app, ["report", str(run), str(calm_run), "--out", str(tmp_path / "cmp")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "cmp" / "index.html").is_file()


def test_bad_input_exits_2(run, tmp_path):
    result = runner.invoke(app, ["report", str(tmp_path / "missing")])
    assert result.exit_code == 2
    assert "is not a folder" in result.output

    empty = RunDirectory.create(
        root=tmp_path, spec_file=run / "spec.yaml", name="empty", meta={"spec_base": "."}, folder=tmp_path / "empty"
    )
    result = runner.invoke(app, ["report", str(empty.path)])
    assert result.exit_code == 2
    assert "has no evaluations yet" in result.output

    blocked = tmp_path / "blocked"
    shutil.copytree(run, blocked)
    shutil.rmtree(blocked / "recordings", ignore_errors=True)
    (blocked / "recordings").write_text("a file where the recordings folder should be")
    result = runner.invoke(app, ["report", str(blocked)])
    assert result.exit_code == 2
    assert "cannot write the recording" in result.output


def test_surrogate_accuracy_is_tabled_when_the_run_has_one(calm_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(calm_run, run)
    per_outer = [
        {
            "outer_iteration": 1,
            "held_out": 99,
            "objective_mae": 3.25,
            "right_cell_fraction": 0.0101,
            "mean_cell_distance": 7.5,
        },
        {
            "outer_iteration": 2,
            "held_out": 97,
            "objective_mae": 0.987654321,
            "right_cell_fraction": 0.25,
            "mean_cell_distance": 2.0,
        },
    ]
    (run / "surrogate.json").write_text(
        json.dumps(
            {
                "held_out": 196,
                "measure_mae": {"goal_distance": 0.123456789},
                "per_outer_iteration": per_outer,
                "fits": [{"outer_iteration": 1, "samples": 100, "occupancy_loss": 3.4, "predictor_loss": 0.01}],
            }
        )
    )
    page = write_report(run, recordings=0).read_text()
    assert "Surrogate accuracy on the proposals it made" in page
    for text in ("measure_mae.goal_distance", "0.123457", "196", "The same, per outer iteration", "0.987654"):
        assert text in page
    assert "occupancy_loss" not in page  # training losses stay in the file


def test_a_two_clause_failure_condition_says_which_clause_held(tmp_path):
    run = toy_run(tmp_path, failure="objective >= 9 or min_goal_distance < 0.03", budget=150, seed=3)
    failures = failures_of(run)
    why = [w for f in failures for w in f["why"]]
    assert any(w.startswith("objective >= 9 (objective=") for w in why)
    assert any(w.startswith("min_goal_distance < 0.03 (min_goal_distance=") for w in why)
    for f in failures:  # each failure names at least one clause, with the value that decided it
        assert f["why"], f

    page = write_report(run, recordings=1).read_text()
    assert "Why they fail" in page
    assert "objective &gt;= 9" in page and "min_goal_distance &lt; 0.03" in page
    # The worst failure of each clause is recorded, the safety clause's too.
    worst_safety = min(
        (f for f in failures if any(w.startswith("min_goal_distance") for w in f["why"])),
        key=lambda f: (-f["objective"], f["id"]),
    )["id"]
    assert (run / "recordings" / f"{worst_safety}.rrd").is_file()


def test_a_second_report_reuses_the_recordings_of_the_first(tmp_path):
    run = toy_run(tmp_path, budget=100, seed=4)
    write_report(run, recordings=2)
    made = {p.name: p.stat().st_mtime_ns for p in (run / "recordings").glob("*.rrd")}
    assert made
    page = write_report(run, recordings=2).read_text()
    assert {p.name: p.stat().st_mtime_ns for p in (run / "recordings").glob("*.rrd")} == made
    assert "0 now, the others by an earlier report of this run" in page
    # A recording whose scenario the index does not vouch for is made again.
    (run / "recordings" / "replays.json").write_text("{not json")
    page = write_report(run, recordings=2).read_text()
    assert all(p.stat().st_mtime_ns != made[p.name] for p in (run / "recordings").glob("*.rrd"))
    assert "were re-simulated from their stored raw theta and seed (now)" in page


def test_the_largest_kinds_failure_is_shown_beside_the_nearest_passing_scenario(run, reported):
    page = reported.read_text()
    representative = load_run(run).clusters[0].representative
    stored = json.loads((run / "counterfactuals" / f"{representative.index}.json").read_text())
    assert "What would have passed" in page and f"Failure {representative.index}, the representative" in page
    assert stored["changed"] and stored["passing"]["objective"] < 8  # the toy's failure condition: objective >= 8
    pair = run / "counterfactuals" / f"{representative.index}.rrd"
    entities = recorded_entities(pair)
    assert {"failure/world/robot", "passing/world/robot", "failure/scenario", "passing/scenario"} <= set(entities)
    assert f'href="../counterfactuals/{pair.name}"' in page
    made = (run / "counterfactuals" / f"{representative.index}.json").stat().st_mtime_ns
    write_report(run, recordings=2)  # a second report reads it back
    assert (run / "counterfactuals" / f"{representative.index}.json").stat().st_mtime_ns == made


def test_a_kinds_representative_shows_what_its_shrunk_version_needs(tmp_path):
    run = toy_run(tmp_path, budget=100, seed=5)
    representative = load_run(run).clusters[0].representative
    page = write_report(run, recordings=0).read_text()
    assert f"hritest shrink {run} --failure {representative.index}" in page  # not shrunk yet: how to
    result = runner.invoke(app, ["shrink", str(run), "--failure", str(representative.index), "--json"])
    assert result.exit_code == 0, result.output
    needed = [name for name, row in json.loads(result.output)["parameters"].items() if row["matters"]]
    page = write_report(run, recordings=0).read_text()
    assert f"{', '.join(needed) or 'nothing: the nominal scenario fails too'} (" in page


def test_a_run_someone_else_wrote_is_reported_only_with_trust(tmp_path, monkeypatch):
    run = toy_run(tmp_path / "theirs", budget=60)
    (run / "archive.csv").unlink()  # so that the report reads the checkpoint's result archive
    shutil.rmtree(run / "recordings", ignore_errors=True)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "another-user"))  # their signature is not ours
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")  # and their plugin file lies outside our project
    for args in (["--recordings", "0"], []):
        result = runner.invoke(app, ["report", str(run), *args])
        assert result.exit_code == 2, result.output
        message = " ".join(result.output.split())
        assert "checkpoint.pkl was not loaded" in message and "--trust" in message, message
    (run / "archive.csv").write_text("evaluation\n")  # the archive is there again: now the plugins are refused
    result = runner.invoke(app, ["report", str(run)])
    assert result.exit_code == 2, result.output
    message = " ".join(result.output.split())
    assert "not started by you" in message and "--trust" in message, message
    assert not any((run / "recordings").glob("*.rrd"))

    (run / "archive.csv").unlink()
    result = runner.invoke(app, ["report", str(run), "--trust"])
    assert result.exit_code == 0, result.output
    assert (run / "report" / "index.html").is_file() and any((run / "recordings").glob("*.rrd"))
    assert not RunDirectory.open(run).written_by_me  # reporting a run does not make it the user's
