"""The Dask backend: the same search code, evaluations on a (local) Dask cluster."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

import pytest

from hritest import search as qd

distributed = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def cluster():
    # A LocalCluster sets OMP_NUM_THREADS=1 and the like in this process's environment for its
    # workers, and leaves them: a search started later in a subprocess would train its surrogate
    # on one thread, not two as in this process, and round differently.
    environment = dict(os.environ)
    try:
        with distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
        ) as local:
            yield local.scheduler_address
    finally:
        os.environ.clear()
        os.environ.update(environment)


def test_a_cluster_search_gives_the_same_archive_as_a_local_one(toy_spec, tmp_path, cluster):
    spec = toy_spec()
    remote = qd.start(
        spec_file=spec,
        out=tmp_path / "remote",
        algorithm="cma_mae",
        budget=300,
        seed=4,
        backend=qd.Backend(cluster=cluster, timeout=10),
    )
    local = qd.start(
        spec_file=spec,
        out=tmp_path / "local",
        algorithm="cma_mae",
        budget=300,
        seed=4,
        backend=qd.Backend(workers=2, timeout=10),
    )
    assert (tmp_path / "remote" / "archive.csv").read_text() == (tmp_path / "local" / "archive.csv").read_text()
    assert remote.state.evaluations == local.state.evaluations == 300


def test_a_plugin_crash_on_a_cluster_fails_its_scenario_only(toy_spec, tmp_path, cluster):
    spec = toy_spec("time_limit: 10.0\n", "time_limit: 10.0\n  params: {fault: raise, fault_above: 0.045}\n")
    found = qd.start(
        spec_file=spec,
        out=tmp_path / "run",
        algorithm="random",
        budget=40,
        seed=1,
        backend=qd.Backend(cluster=cluster, timeout=10),
    )
    records = found.run_dir.evaluations()
    assert {r.status for r in records if r.theta[4] > 0.045} == {"plugin_error"}
    assert {r.status for r in records if r.theta[4] <= 0.045} == {"ok"}


@pytest.fixture
def separate_cluster(tmp_path):
    """A scheduler and two single-threaded workers, each its own process as on real machines
    (no nanny, so a killed worker stays dead); yields the scheduler file and the workers."""
    file = tmp_path / "scheduler.json"
    dask = [sys.executable, "-m", "dask"]
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    processes = [
        subprocess.Popen([*dask, "scheduler", "--port", "0", "--no-dashboard", "--scheduler-file", file], **quiet)
    ]
    try:
        worker = [*dask, "worker", "--scheduler-file", file, "--nthreads", "1", "--no-nanny", "--no-dashboard"]
        processes += [subprocess.Popen(worker, **quiet) for _ in range(2)]
        with distributed.Client(scheduler_file=str(file), timeout=30) as client:
            client.wait_for_workers(2, timeout=30)
            address = client.scheduler.address
        yield address, processes[1:]
    finally:
        for process in processes:
            process.kill()
            process.wait()


def test_a_worker_killed_mid_run_loses_no_evaluation(toy_spec, tmp_path, separate_cluster):
    address, workers = separate_cluster
    spec = toy_spec("time_limit: 10.0\n", "time_limit: 10.0\n  params: {delay: 0.05}\n")
    lines = tmp_path / "run" / "evaluations.jsonl"
    killed = threading.Event()

    def kill_a_worker_mid_run() -> None:
        while not (lines.exists() and len(lines.read_text().splitlines()) >= 30):
            time.sleep(0.02)
        workers[0].kill()
        killed.set()

    threading.Thread(target=kill_a_worker_mid_run, daemon=True).start()
    found = qd.start(
        spec_file=spec,
        out=tmp_path / "run",
        algorithm="random",
        budget=150,
        seed=2,
        backend=qd.Backend(cluster=address, timeout=20),
    )
    assert killed.is_set() and workers[0].wait() is not None
    records = found.run_dir.evaluations()
    assert sorted(r.index for r in records) == list(range(150))
    assert {r.status for r in records} == {"ok"}
    assert len(lines.read_text().splitlines()) == 150  # each evaluation once
