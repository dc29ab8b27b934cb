"""The Dask backend: the same search code, evaluations on a (local) Dask cluster."""

from __future__ import annotations

import pytest

from hritest import search as qd

distributed = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as local:
        yield local.scheduler_address


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
    statuses = {r["status"] for r in found.records.values() if r["theta"][4] > 0.045}
    assert statuses == {"plugin_error"}
    assert {r["status"] for r in found.records.values() if r["theta"][4] <= 0.045} == {"ok"}
