"""docs/writing-a-domain.md: its example is the code in docs/examples/crossing/, and that code works."""

from __future__ import annotations

import difflib
import json
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hritest import search as qd
from hritest.cli import app
from hritest.domain import compile_spec
from hritest.evaluate import evaluate
from hritest.spec import load_spec

DOCS = Path(__file__).parent.parent / "docs"
GUIDE = DOCS / "writing-a-domain.md"
EXAMPLE = DOCS / "examples" / "crossing"
SPEC = EXAMPLE / "crossing.yaml"
# A file's text, shown whole: the marker names the file (relative to the guide), the next block holds it.
INCLUDED = re.compile(r"<!-- example: (?P<path>\S+) -->\n```\w*\n(?P<text>.*?)^```$", re.S | re.M)


def test_the_guide_shows_the_example_files_as_they_are():
    blocks = {m["path"]: m["text"] for m in INCLUDED.finditer(GUIDE.read_text())}
    assert sorted(blocks) == ["examples/crossing/crossing.yaml", "examples/crossing/crossing_plugins.py"]
    for path, shown in blocks.items():
        actual = (GUIDE.parent / path).read_text()
        diff = "".join(
            difflib.unified_diff(
                actual.splitlines(True), shown.splitlines(True), f"docs/{path}", f"its block in {GUIDE.name}"
            )
        )
        assert shown == actual, f"copy docs/{path} into its block in docs/{GUIDE.name}:\n{diff}"


def test_the_example_compiles_and_its_nominal_scenario_is_ok_and_repeatable():
    domain = compile_spec(load_spec(SPEC))
    assert domain.world is None and domain.grids == {}
    first, again = evaluate(domain, domain.nominal, seed=3), evaluate(domain, domain.nominal, seed=3)
    assert first.status == "ok", first.message
    assert not first.failure  # the nominal pedestrian waits and the robot arrives
    assert (first.objective, first.measures.tolist(), first.metrics) == (
        again.objective,
        again.measures.tolist(),
        again.metrics,
    )


def test_the_example_passes_check():
    result = CliRunner().invoke(app, ["check", str(SPEC)])
    assert result.exit_code == 0, result.output


def outcome(run: Path) -> list[tuple]:
    records = [json.loads(line) for line in (run / "evaluations.jsonl").read_text().splitlines()]
    return sorted((r["index"], r["status"], r["objective"], tuple(r["measures"])) for r in records)


def test_a_small_search_of_the_example_finds_failures_and_the_same_seed_repeats_it(tmp_path):
    found = qd.start(
        spec_file=SPEC,
        out=tmp_path / "a",
        algorithm="cma_mae",
        budget=160,
        seed=1,
        backend=qd.Backend(workers=2, timeout=20),
    )
    assert {status for _, status, _, _ in outcome(tmp_path / "a")} == {"ok"}
    failures = found.failures()
    assert failures, "cma_mae found no collision or deadlock in 160 scenarios"
    qd.start(
        spec_file=SPEC,
        out=tmp_path / "b",
        algorithm="cma_mae",
        budget=160,
        seed=1,
        backend=qd.Backend(workers=1, timeout=20),
    )
    assert outcome(tmp_path / "a") == outcome(tmp_path / "b")
    assert (tmp_path / "a" / "archive.csv").read_text() == (tmp_path / "b" / "archive.csv").read_text()


@pytest.mark.parametrize(
    ("theta", "collides"),
    [([8.3, 1.23, 4.31, 0.04, 1.43], True), ([6.79, 1.19, 4.85, 1.69, 0.8], False)],
    ids=["impatient pedestrian: collision", "robot stops in the way: deadlock"],
)
def test_the_two_kinds_of_failure_the_guide_describes_happen(theta, collides):
    evaluation = evaluate(compile_spec(load_spec(SPEC)), np.array(theta))
    assert evaluation.failure and evaluation.objective == 20
    assert (evaluation.metrics["min_distance"] < 0.55) == collides
    assert (evaluation.metrics["time_stopped"] > 5) != collides  # a deadlock: both wait to the time limit
