"""CVT archives: a spec with three measures searches with every algorithm and reports."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hritest import search as qd
from hritest.domain import compile_spec
from hritest.errors import SpecError
from hritest.report import write_report
from hritest.search import archives
from hritest.spec import load_spec

MEASURES = """measures:
  - {name: goal_distance, expr: min_goal_distance, range: [0, 0.32]}
  - {name: variation, expr: norm(noise), range: [0, 0.087]}
  - {name: spread, expr: abs(g0y - g1y), range: [0, 0.26]}
archive: {type: cvt, cells: 60, samples: 5000}
"""
GRID = """measures:
  - {name: goal_distance, expr: min_goal_distance, range: [0, 0.32], cells: 16}
  - {name: variation, expr: norm(noise), range: [0, 0.087], cells: 16}
"""


@pytest.fixture
def cvt_spec(toy_spec):
    text = toy_spec().read_text().replace(GRID, MEASURES)
    surrogate = "  surrogate: {initial_evaluations: 20, inner_iterations: 5, epochs: 2}\n"
    return toy_spec(text=text.replace("search:\n", "search:\n" + surrogate))


def test_three_measures_need_a_cvt_archive(toy_spec):
    three = MEASURES.replace("archive: {type: cvt, cells: 60, samples: 5000}\n", "")
    with pytest.raises(SpecError, match="3 measures need a cvt archive"):
        load_spec(toy_spec(GRID, three))
    with pytest.raises(SpecError, match="a cvt archive needs its number of cells"):
        load_spec(toy_spec(GRID, MEASURES.replace("cells: 60, ", "")))


def test_the_tessellation_is_the_specs_whatever_the_seed(cvt_spec):
    domain = compile_spec(load_spec(cvt_spec))
    one, other = archives.result_archive(domain, seed=1), archives.result_archive(domain, seed=2)
    assert one.cells == 60 and np.array_equal(one.centroids, other.centroids)


@pytest.mark.parametrize("algorithm", ["random", "cma_mae", "sas", "dsas"])
def test_every_algorithm_searches_a_cvt_archive_and_reports(cvt_spec, tmp_path, algorithm):
    found = qd.start(
        spec_file=cvt_spec,
        out=tmp_path / "run",
        algorithm=algorithm,
        budget=60,
        seed=0,
        backend=qd.Backend(workers=1),
        surrogate=qd.SurrogateOptions(device="cpu"),
    )
    records = [json.loads(line) for line in (tmp_path / "run" / "evaluations.jsonl").read_text().splitlines()]
    assert len(records) == 60 and {r["status"] for r in records} == {"ok"}
    assert found.state.result.stats.num_elites > 3
    page = write_report(tmp_path / "run", recordings=0).read_text()
    assert "of 60 cells" in page and (tmp_path / "run" / "report" / "archive.png").stat().st_size > 10_000
