"""What a resume reads is checked before it is used: the checkpoint's signature, its state, and
its agreement with ``run.json``, ``spec.yaml``, ``evaluations.jsonl`` and ``occupancy.f32``. A
failed check exits 2, names the file, and leaves the run directory as it was."""

from __future__ import annotations

import json
import os
import pickle
import tarfile
from dataclasses import asdict, fields, replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hritest import search as qd
from hritest.cli import app
from hritest.records import EvaluationRecord, Status
from hritest.rundir import SIGNED, RunDirectory, RunDirectoryError
from hritest.search.state import SearchState, check_resumable, evaluation_seed, load_state

runner = CliRunner()
RESULTS = Path(__file__).parents[2] / "benchmarks" / "results"


def finished_run(toy_spec, tmp_path: Path) -> Path:
    """A run of two whole MAP-Elites batches (of 20): one that can be resumed with a larger budget."""
    qd.start(
        spec_file=toy_spec(), out=tmp_path / "run", budget=40, seed=0, algorithm="map_elites",
        backend=qd.Backend(workers=1),
    )  # fmt: skip
    return tmp_path / "run"


def files(run: Path) -> dict[str, bytes]:
    """The run's files (not the lock file, which only says who holds the lock)."""
    return {p.name: p.read_bytes() for p in run.iterdir() if p.is_file() and not p.name.startswith(".")}


def resume(run: Path, *args: str):
    return runner.invoke(app, ["search", "--resume", str(run), "--workers", "1", "--quiet", *args])


def refused(run: Path, *words: str, args: tuple[str, ...] = ()) -> str:
    """Resumes ``run``, expecting exit 2 with ``words`` in the message and nothing changed."""
    before = files(run)
    result = resume(run, *args)
    assert result.exit_code == 2, result.output
    message = " ".join(result.output.split())
    assert all(word in message for word in words), message
    assert files(run) == before
    return message


class Marker:
    """A pickle that, when loaded, creates a file: what a doctored checkpoint could do."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __reduce__(self):
        return open, (str(self.path), "w")


def test_a_doctored_checkpoint_is_never_unpickled_by_resume_or_report(toy_spec, tmp_path):
    run = finished_run(toy_spec, tmp_path)
    marker = tmp_path / "marker"
    doctored = pickle.dumps(Marker(marker))
    (run / "archive.csv").unlink()  # so that the report reads the checkpoint's result archive
    for raw, why in ((doctored, "not signed"), (SIGNED + bytes(32) + doctored, "does not match your key")):
        (run / "checkpoint.pkl").write_bytes(raw)
        refused(run, "checkpoint.pkl", why, "--trust")
        before = files(run)
        result = runner.invoke(app, ["report", str(run), "--recordings", "0"])
        assert result.exit_code == 2 and why in " ".join(result.output.split()), result.output
        assert files(run) == before
        assert not marker.exists()
    # The opt-in is real: trusted, the pickle runs (and is then refused as no search state).
    refused(run, "checkpoint.pkl", "holds a TextIOWrapper", args=("--trust",))
    assert marker.exists()


def test_a_checkpoint_from_before_the_typed_state_resumes_when_trusted(toy_spec, tmp_path):
    run = finished_run(toy_spec, tmp_path)
    state = load_state(RunDirectory.open(run))
    assert isinstance(state, SearchState) and state.evaluations == 40
    legacy = {f.name: getattr(state, f.name) for f in fields(state)}  # as hritest wrote it before
    legacy.update(budget=60, progress=[asdict(row) for row in state.progress])
    (run / "checkpoint.pkl").write_bytes(pickle.dumps(legacy))  # and unsigned
    refused(run, "not signed", "--trust")

    result = resume(run, "--trust")
    assert result.exit_code in (0, 1) and isinstance(result.exception, SystemExit | None), result.output
    again = load_state(RunDirectory.open(run))  # signed now, and typed
    assert again.evaluations == 60 and len(again.progress) > len(state.progress)
    assert sorted(r.index for r in RunDirectory.open(run).evaluations()) == list(range(60))


def test_a_real_run_from_before_signing_loads_only_when_trusted(tmp_path):
    with tarfile.open(RESULTS / "teleop-paper-sas-s0.tar.xz") as tar:
        tar.extractall(tmp_path, filter="data")
    (path,) = tmp_path.iterdir()
    run = RunDirectory.open(path)
    with pytest.raises(RunDirectoryError, match="not signed"):
        load_state(run)
    state = load_state(run, trust=True)
    assert (state.algorithm, state.seed, state.evaluations) == ("sas", 0, 10000)
    assert state.progress[-1].evaluations == 10000 and state.pending is None
    assert state.result.stats.num_elites == len((path / "archive.csv").read_text().splitlines()) - 1


def test_resume_refuses_evaluations_that_disagree_with_the_checkpoint(toy_spec, tmp_path):
    run = finished_run(toy_spec, tmp_path)
    lines = (run / "evaluations.jsonl").read_text().splitlines(keepends=True)

    (run / "evaluations.jsonl").write_text("".join(lines[:-3]))  # shortened
    refused(run, "evaluations.jsonl", "counts 40 told evaluations", "are missing")
    (run / "evaluations.jsonl").write_text("".join([*lines[:10], lines[5], *lines[10:]]))  # one line twice
    refused(run, "evaluations.jsonl", "twice")
    (run / "evaluations.jsonl").write_text("".join([lines[0], "{not json\n", *lines[2:]]))
    refused(run, "evaluations.jsonl:2 is corrupt")
    other = json.loads(lines[5]) | {"seed": 1}  # an evaluation of another run (lines are in arrival order)
    (run / "evaluations.jsonl").write_text("".join([*lines[:5], json.dumps(other) + "\n", *lines[6:]]))
    refused(run, f"evaluation {other['index']} is not one of this run's")
    (run / "evaluations.jsonl").write_text("".join(lines))

    state = load_state(RunDirectory.open(run))
    RunDirectory.open(run).save_checkpoint(replace(state, evaluations=50, budget=60))  # counts too many
    refused(run, "evaluations 40, 41, 42, 43, 44 and 5 more are missing")
    RunDirectory.open(run).save_checkpoint(replace(state, seed=4))
    refused(run, "checkpoint.pkl is of a run with seed 4", "run.json says 0")


def test_resume_refuses_a_spec_edited_in_the_run_and_a_stray_occupancy_file(toy_spec, tmp_path):
    run = finished_run(toy_spec, tmp_path)
    spec = (run / "spec.yaml").read_text()
    (run / "spec.yaml").write_text(spec + "# a comment\n")
    refused(run, "spec.yaml is not the spec this run was started with")
    (run / "spec.yaml").write_text(spec)
    (run / "occupancy.f32").write_bytes(bytes(8))  # grids for a task that declares none
    refused(run, "occupancy.f32 holds 8 bytes", "belongs to another task")


def record(index: int, seed: int) -> EvaluationRecord:
    return EvaluationRecord(
        index=index, batch=1, status=Status.OK, failure=False, objective=1.0, search_objective=1.0, measures=(0.5,),
        repair_cost=0.0, regions={}, theta=(0.0,), theta_repaired=(0.0,), metrics={},
        seed=evaluation_seed(seed, index), seconds=0.0,
    )  # fmt: skip


def test_a_truncated_occupancy_file_is_refused_and_a_torn_record_is_not(tmp_path):
    spec = tmp_path / "spec.yaml"
    spec.write_text("name: any\n")
    run = RunDirectory.create(
        root=tmp_path, spec_file=spec, name="any", meta={"algorithm": "random", "seed": 3}, folder=tmp_path / "run"
    )
    shape = (2, 32, 32)
    for i in range(4):
        run.append(record(i, 3), np.ones(shape, np.float32), shape)
    state = SearchState(algorithm="random", budget=10, seed=3, proposer=None, result=None, evaluations=4)
    records = run.evaluations()
    assert check_resumable(state, run=run, records=records, dim=1, grid_shape=shape) == 4

    with open(run.path / "occupancy.f32", "ab") as handle:  # a kill while writing the next record
        handle.write(bytes(100))
    assert check_resumable(state, run=run, records=records, dim=1, grid_shape=shape) == 4
    size = (run.path / "occupancy.f32").stat().st_size
    os.truncate(run.path / "occupancy.f32", 3 * 2 * 32 * 32 * 4 + 10)
    with pytest.raises(RunDirectoryError, match=r"occupancy.f32 holds 24586 bytes, but the 4 evaluations"):
        check_resumable(state, run=run, records=records, dim=1, grid_shape=shape)
    assert size > (run.path / "occupancy.f32").stat().st_size  # it only checked; nothing was zero-filled
    with pytest.raises(RunDirectoryError, match="theta's size differs"):
        check_resumable(state, run=run, records=records, dim=2, grid_shape=shape)


def test_resume_takes_no_settings_it_would_ignore(toy_spec, tmp_path):
    run = finished_run(toy_spec, tmp_path)
    refused(run, "--budget, --seed", "cannot change a run", args=("--budget", "50", "--seed", "1"))
    result = runner.invoke(app, ["search", str(toy_spec()), "--trust", "--out", str(tmp_path / "new")])
    assert result.exit_code == 2 and "--resume" in result.output and not (tmp_path / "new").exists()
