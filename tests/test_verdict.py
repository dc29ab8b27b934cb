"""The corpus verdict: one function decides passing, regression, still failing, flaky, now passing or error."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hritest.corpus import dump_entry, load_entry
from hritest.domain import compile_spec
from hritest.evaluate import evaluate
from hritest.records import Status, scenario_digest
from hritest.spec import load_spec
from hritest.verdict import SeedReplay, Verdict, changes_since, judge

FAILS = [0.6, 0.05, 0.6, 0.05, 0.05, 0.05, 0.05]  # goals on one spot, a noisy human: objective 10
PASSES = [0.52, -0.08, 0.68, 0.18, 0.0, 0.0, 0.0]  # goals far apart, a quiet human


@pytest.fixture
def toy(toy_spec):
    return compile_spec(load_spec(toy_spec()))


def replay(domain, theta, seed=0) -> SeedReplay:
    evaluation = evaluate(domain, np.array(theta), seed=seed)
    return SeedReplay.from_json(SeedReplay.of(evaluation, [m.name for m in domain.measures]).to_json())


def entry_of(domain, tmp_path, *, status: str, theta=FAILS):
    evaluation = evaluate(domain, np.array(theta), seed=0)
    labels = domain.space.labels
    scenario = scenario_digest("0" * 64, evaluation.theta_repaired, 0)
    path = tmp_path / "toy" / f"{scenario[:12]}.yaml"
    path.parent.mkdir(exist_ok=True)
    data = {
        "format": 1,
        "status": status,
        "spec": "../spec.yaml",
        "spec_name": "toy",
        "spec_digest": "0" * 64,
        "seed": 0,
        "objective": 10.0,
        "measures": {"goal_distance": 0.0, "variation": 0.0866},
        "theta": dict(zip(labels, theta)),
        "theta_repaired": dict(zip(labels, evaluation.theta_repaired.tolist())),
        "scenario_digest": scenario,
    }
    path.write_text(dump_entry(data))
    return load_entry(path)


def test_the_verdict_of_every_combination(toy, tmp_path):
    fixed, open_ = entry_of(toy, tmp_path, status="fixed"), entry_of(toy, tmp_path, status="open")
    fail, ok = replay(toy, FAILS), replay(toy, FAILS)
    ok = replace(ok, failure=False, clauses=tuple(replace(c, holds=False) for c in ok.clauses))
    assert fail.fired and fail.fired[0].text == "objective >= 8"
    cases = [
        (fixed, [ok], Verdict.PASSING, None),
        (fixed, [fail], Verdict.REGRESSION, 1.0),
        (fixed, [ok, fail], Verdict.REGRESSION, 0.5),
        (open_, [fail, fail], Verdict.STILL_FAILING, 1.0),
        (open_, [ok, fail, ok, ok], Verdict.FLAKY, 0.25),
        (open_, [ok], Verdict.NOW_PASSING, 0.0),
    ]
    for entry, replays, verdict, rate in cases:
        judged = judge(entry, replays, changes=[])
        assert (judged.verdict, judged.failure_rate) == (verdict, rate), (entry.status, replays)
    assert "fails again with 1 of 2 seeds: objective >= 8 (objective=10)" in judge(fixed, [ok, fail], changes=[]).reason


def test_an_evaluation_that_did_not_complete_is_an_error_whatever_the_status(toy, tmp_path):
    broken = replace(replay(toy, FAILS), status=Status.PLUGIN_ERROR, message="boom")
    for status in ("open", "fixed"):
        judged = judge(entry_of(toy, tmp_path, status=status), [broken], changes=["task plugin source"])
        assert judged.verdict is Verdict.ERROR and "status plugin_error" in judged.reason and "boom" in judged.reason
        assert judged.changed == "(spec or plugins changed since this was recorded: task plugin source)"


def test_a_raw_theta_that_no_longer_repairs_to_the_stored_one_is_an_error_unless_the_space_changed(toy, tmp_path):
    entry = entry_of(toy, tmp_path, status="fixed")
    moved = replace(replay(toy, PASSES), failure=False)
    judged = judge(entry, [moved], changes=[])
    assert judged.verdict is Verdict.ERROR
    assert "field 'theta' does not repair to the stored field 'theta_repaired' (g0x:" in judged.reason
    assert judge(entry, [moved], changes=["constraints"]).verdict is Verdict.PASSING


def test_changes_are_the_parts_that_differ_or_for_format_1_the_spec_file(toy, tmp_path):
    entry = entry_of(toy, tmp_path, status="open")
    assert changes_since(entry, parts_now={"task": "a"}, spec_digest_now="0" * 64) == []
    assert changes_since(entry, parts_now={"task": "a"}, spec_digest_now="1" * 64)[0].startswith("the spec file")
    entry = replace(entry, outcome_parts={"task": "a", "objective": "b"})
    assert changes_since(entry, parts_now={"task": "a", "objective": "c"}, spec_digest_now="1" * 64) == ["objective"]
