"""The run directory: its append-only evaluation files, with occupancy grids and without (a task
that declares none, whose records are of size zero); its signatures, which decide what of it may
run code; and its lock, which lets one search write it."""

from __future__ import annotations

import json
import multiprocessing
import os
import shutil
import stat
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hritest import search as qd
from hritest.cli import app
from hritest.records import EvaluationRecord, Status
from hritest.rundir import RunDirectory, RunDirectoryError, key_path, signing_key

runner = CliRunner()


def record(index: int) -> EvaluationRecord:
    return EvaluationRecord(
        index=index, batch=1, status=Status.OK, failure=False, objective=1.0, search_objective=1.0, measures=(0.5,),
        repair_cost=0.0, regions={}, theta=(0.0,), theta_repaired=(0.0,), metrics={}, seed=index, seconds=0.0,
    )  # fmt: skip


def new_run(tmp_path: Path) -> RunDirectory:
    spec = tmp_path / "spec.yaml"
    spec.write_text("name: any\n")
    return RunDirectory.create(root=tmp_path, spec_file=spec, name="any", meta={}, folder=tmp_path / "run")


@pytest.mark.parametrize("channels", [0, 2])
def test_evaluations_and_their_grids_append_read_and_truncate_together(tmp_path, channels):
    run = new_run(tmp_path)
    shape = (channels, 32, 32)
    grids = np.random.default_rng(0).random((4, *shape), dtype=np.float32)
    for i, grid in enumerate(grids):
        run.append(record(i), None if i == 2 else grid, shape)  # a failed evaluation has no grids
    expected = grids.copy()
    expected[2] = 0
    assert [r.index for r in run.evaluations()] == [0, 1, 2, 3]
    np.testing.assert_array_equal(run.occupancy(shape), expected)
    assert (run.path / "occupancy.f32").stat().st_size == grids.nbytes  # no bytes at all without grids

    with open(run.path / "evaluations.jsonl", "a") as handle:  # a kill in the middle of a line
        handle.write('{"index": 4, "tor')
    assert len(run.evaluations()) == 4
    assert run.occupancy(shape).shape == (4, *shape)

    run.truncate(2, shape)  # what resuming does
    assert [r.index for r in run.evaluations()] == [0, 1]
    np.testing.assert_array_equal(run.occupancy(shape), expected[:2])

    run.append(record(2), grids[3], shape)
    assert [r.index for r in run.evaluations()] == [0, 1, 2]
    np.testing.assert_array_equal(run.occupancy(shape), np.concatenate([expected[:2], grids[3:]]))
    run.truncate(0, shape)
    assert run.evaluations() == [] and run.occupancy(shape).shape == (0, *shape)


def test_the_signing_key_is_made_once_and_kept_private(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    key = signing_key()
    path = key_path()
    assert path == tmp_path / "config" / "hritest" / "signing.key"
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and len(key) == 32
    assert signing_key() == key
    path.chmod(0o640)
    with pytest.raises(RunDirectoryError, match="chmod 600"):
        signing_key()
    (tmp_path / "file").write_text("")
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "file"))  # no folder can be made there
    with pytest.raises(RunDirectoryError, match="cannot be made or read"):
        signing_key()
    with pytest.raises(RunDirectoryError, match="cannot be made or read"):
        new_run(tmp_path)
    assert not (tmp_path / "run").exists()  # nothing half-made to block the next try


def test_a_checkpoint_loads_only_as_its_writer_signed_it(tmp_path, monkeypatch):
    run = new_run(tmp_path)
    run.save_checkpoint({"evaluations": 3})
    assert run.load_checkpoint() == {"evaluations": 3}
    raw = (run.path / "checkpoint.pkl").read_bytes()
    (run.path / "checkpoint.pkl").write_bytes(raw[:-2] + bytes([raw[-2] ^ 1]) + raw[-1:])  # one bit altered
    with pytest.raises(RunDirectoryError, match="does not match your key"):
        run.load_checkpoint()
    (run.path / "checkpoint.pkl").write_bytes(raw)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "another-user"))
    with pytest.raises(RunDirectoryError, match="does not match your key"):
        run.load_checkpoint()
    assert run.load_checkpoint(trust=True) == {"evaluations": 3}
    assert not RunDirectory.open(run.path).written_by_me
    run.adopt()  # as benchmarks/stash.py restores a run packed on another machine
    assert run.load_checkpoint() == {"evaluations": 3} and RunDirectory.open(run.path).written_by_me


def files(run: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in run.iterdir() if p.is_file() and not p.name.startswith(".")}


def toy_run(toy_spec, tmp_path: Path) -> Path:
    qd.start(
        spec_file=toy_spec(), out=tmp_path / "run", budget=20, seed=0, algorithm="map_elites",
        backend=qd.Backend(workers=1),
    )  # fmt: skip
    return tmp_path / "run"


def test_a_second_search_of_a_run_is_refused_while_one_writes_it(toy_spec, tmp_path):
    run = toy_run(toy_spec, tmp_path)
    before = files(run)
    with RunDirectory.open(run).lock():
        result = runner.invoke(app, ["search", "--resume", str(run), "--workers", "1", "--quiet"])
        assert result.exit_code == 2, result.output
        assert f"being written by another search (process {os.getpid()})" in " ".join(result.output.split())
        assert files(run) == before
    result = runner.invoke(app, ["search", "--resume", str(run), "--workers", "1", "--quiet"])
    assert result.exit_code in (0, 1), result.output  # released with the search that held it


def live_on(started) -> None:
    started.set()
    time.sleep(60)


def test_a_forked_worker_does_not_keep_the_run_locked(tmp_path):
    run = new_run(tmp_path)
    fork = multiprocessing.get_context("fork")
    started = fork.Event()
    with run.lock():
        child = fork.Process(target=live_on, args=(started,))
        child.start()  # as a process pool starts its workers
        assert started.wait(30)
    try:
        with run.lock():  # the child lives on, and the lock is free
            pass
    finally:
        child.kill()
        child.join()


def test_plugin_files_of_a_run_someone_else_started_run_only_from_the_project(toy_spec, tmp_path, monkeypatch):
    run = toy_run(toy_spec, tmp_path)
    meta = json.loads((run / "run.json").read_text())
    del meta["signature"]  # as a run from another user (or an older hritest) has it
    (run / "run.json").write_text(json.dumps(meta))
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    before = files(run)
    for args in (["search", "--resume", str(run), "--quiet"], ["replay", str(run), "--failure", "0"]):
        result = runner.invoke(app, args)
        assert result.exit_code == 2, result.output
        message = " ".join(result.output.split())
        assert "not started by you" in message and f"plugin file {tmp_path / 'toy_plugins.py'}" in message
        assert files(run) == before
    assert RunDirectory.open(run).plugin_base(trust=True) == tmp_path
    monkeypatch.chdir(tmp_path)  # the project that holds the plugins
    assert RunDirectory.open(run).plugin_base() == tmp_path
    monkeypatch.chdir(tmp_path / "elsewhere")
    result = runner.invoke(app, ["search", "--resume", str(run), "--workers", "1", "--quiet", "--trust"])
    assert result.exit_code in (0, 1), result.output  # and its report re-simulated failures
    assert RunDirectory.open(run).written_by_me  # trusted once, the run is the user's

    monkeypatch.chdir(tmp_path)
    shutil.copy(tmp_path / "toy_plugins.py", run / "toy_plugins.py")  # plugins that came with the run
    (run / "run.json").write_text(json.dumps(meta | {"spec_base": str(run)}))
    with pytest.raises(RunDirectoryError, match="outside your project"):
        RunDirectory.open(run).plugin_base()
