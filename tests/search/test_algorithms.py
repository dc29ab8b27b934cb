"""The model-free algorithms' schedulers, and CMA-ES compiled before a search's clock starts."""

from __future__ import annotations

import numpy as np
from ribs.emitters.opt import CMAEvolutionStrategy

from hritest.domain import load_domain
from hritest.search import algorithms, archives

COMPILED = (CMAEvolutionStrategy._transform_and_check_sol, CMAEvolutionStrategy._calc_cov_update)


def test_compiling_cma_es_leaves_nothing_for_a_real_search_to_compile():
    # numba compiles once per set of argument types: a search's CMA-MAE, over a spec's own
    # dimensions and archive, must find every signature it calls compiled by the warm-up.
    algorithms.compile_cma_es()
    before = [set(f.signatures) for f in COMPILED]
    assert all(before)
    domain = load_domain("specs/teleop.yaml")
    scheduler = algorithms.scheduler(domain, "cma_mae", archives.search_archive(domain, seed=0), seed=0)
    rng = np.random.default_rng(0)
    low, high = np.array(domain.archive_ranges, dtype=float).T
    for _ in range(2):
        solutions = scheduler.ask()
        measures = rng.uniform(low, high, size=(len(solutions), len(low)))
        scheduler.tell(rng.uniform(0, 10, len(solutions)), measures)
    assert [set(f.signatures) for f in COMPILED] == before
