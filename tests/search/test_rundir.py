"""The run directory's append-only evaluation files, with occupancy grids and without (a task
that declares none, whose records are of size zero)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hritest.records import EvaluationRecord, Status
from hritest.rundir import RunDirectory


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
