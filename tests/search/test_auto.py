"""``--algorithm auto``: it measures every arm, follows the best rate, and says why in the run."""

from __future__ import annotations

import csv
import json

from typer.testing import CliRunner

from hritest import search as qd
from hritest.cli import app
from hritest.rundir import RunDirectory
from hritest.search.auto import ARMS

runner = CliRunner()
TWO = qd.Backend(workers=2, timeout=20)


def test_auto_measures_each_arm_then_spends_each_batch_on_the_best_rate(toy_spec, tmp_path):
    spec = toy_spec("time_limit: 10.0\n", "time_limit: 10.0\n  params: {delay: 0.002}\n")
    run = tmp_path / "run"
    found = qd.start(
        spec_file=spec,
        out=run,
        algorithm="auto",
        budget=2500,
        seed=4,
        backend=TWO,
        surrogate=qd.SurrogateOptions(inner_iterations=50, device="cpu"),
    )
    log = json.loads((run / "auto.json").read_text())
    batches = log["batches"]
    # Each arm measured once (SAS once it has data, an arm whose batch costs more, later).
    firsts = [b["arm"] for b in batches if b["reason"] == "first measurement"]
    assert sorted(firsts) == sorted(ARMS) and firsts[0] == "random"
    for b in batches:
        rates = b["rates"]
        if b["reason"] == "best rate":
            assert rates[b["arm"]] == max(rates.values())
        elif b["reason"] != "first measurement":  # a losing arm, measured again
            assert b["reason"].startswith("re-measure") and rates[b["arm"]] < max(rates.values())
    assert sum(b["evaluations"] for b in batches) == found.state.evaluations == 2500

    # Where the time went is in run.json and progress.csv too.
    meta = json.loads((run / "run.json").read_text())
    assert meta["algorithm"] == "auto" and set(meta["auto"]["arms"]) == set(ARMS)
    assert sum(a["evaluations"] for a in meta["auto"]["arms"].values()) == 2500
    with open(run / "progress.csv", newline="") as handle:
        proposers = [row["proposer"] for row in csv.DictReader(handle)]
    assert proposers == [b["arm"] for b in batches]
    # SAS trained on what every arm simulated.
    assert found.state.proposer.arms["sas"].trained > 100


def test_auto_stopped_by_its_time_limit_resumes_and_keeps_its_history(toy_spec, tmp_path):
    spec = toy_spec("time_limit: 10.0\n", "time_limit: 10.0\n  params: {delay: 0.01}\n")
    run = tmp_path / "run"
    args = ["--algorithm", "auto", "--workers", "2", "--quiet", "--inner-iterations", "30", "--device", "cpu"]
    first = runner.invoke(app, ["search", str(spec), "--time-limit", "6", "--out", str(run), *args])
    assert first.exit_code in (0, 1), first.output
    before = json.loads((run / "auto.json").read_text())["batches"]
    again = runner.invoke(app, ["search", "--resume", str(run), "--time-limit", "4", "--workers", "2", "--quiet"])
    assert again.exit_code in (0, 1), again.output
    after = json.loads((run / "auto.json").read_text())["batches"]
    assert after[: len(before)] == before and len(after) > len(before)
    indices = sorted(r.index for r in RunDirectory.open(run).evaluations())
    assert indices == list(range(len(indices)))
    assert "auto" in (run / "report" / "index.html").read_text()
