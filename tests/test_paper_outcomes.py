"""The paper's two domains give the outcomes they gave before hritest's domain-neutral contract,
its typed records and its module splits: the same status, failure verdict, objective and
measures for the same theta and seed.

``fixtures/paper_outcomes.json`` was written by the code of commit ffab5a8 (random thetas in the
bounds, seed i for the i-th). The tolerance allows for another CPU's rounding (one tick is 0.025
s), not for a change in behaviour.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hritest.domain import compile_spec
from hritest.evaluate import evaluate
from hritest.spec import load_spec

ROOT = Path(__file__).parent
PINNED = json.loads((ROOT / "fixtures" / "paper_outcomes.json").read_text())
CASES = [(spec, i) for spec, rows in PINNED.items() for i in range(len(rows))]


@pytest.fixture(scope="module")
def domains():
    return {spec: compile_spec(load_spec(ROOT.parent / "specs" / f"{spec}.yaml")) for spec in PINNED}


@pytest.mark.parametrize(("spec", "case"), CASES, ids=[f"{s}-{i}" for s, i in CASES])
def test_the_same_theta_and_seed_give_the_same_outcome(domains, spec, case):
    pinned = PINNED[spec][case]
    evaluation = evaluate(domains[spec], np.array(pinned["theta"]), seed=pinned["seed"])
    assert evaluation.status == pinned["status"] and evaluation.failure is pinned["failure"]
    assert evaluation.objective == pytest.approx(pinned["objective"], abs=0.05)
    assert evaluation.measures.tolist() == pytest.approx(pinned["measures"], rel=1e-3, abs=1e-4)
