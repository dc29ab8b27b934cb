"""``--algorithm auto``: it measures every arm, follows the best rate, and says why in the run."""

from __future__ import annotations

import csv
import itertools
import json
import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from typer.testing import CliRunner

from hritest import search as qd
from hritest.cli import app
from hritest.domain import load_domain
from hritest.rundir import RunDirectory
from hritest.search import algorithms, auto
from hritest.search.auto import ARMS

runner = CliRunner()
TWO = qd.Backend(workers=2, timeout=20)


def test_auto_measures_each_arm_then_spends_each_stint_on_the_best_rate(toy_spec, tmp_path, monkeypatch):
    # A toy run lasts seconds: short stints, and exploring allowed 60 % of it, so that every
    # arm gets measured (and some re-measured) in that time.
    monkeypatch.setattr(auto, "MIN_STINT", 0.2)
    monkeypatch.setattr(auto, "EXPLORE", 0.6)
    spec = toy_spec(
        "time_limit: 10.0\n",
        "time_limit: 10.0\n  params: {delay: 0.002}\n",
    )
    # The paper's schedule in the spec, which auto's SAS arm does not take (auto.sas_options).
    extra = "  emitter: {emitters: 4, batch_size: 25}\n  surrogate: {training: paper, selection: random}\n"
    spec.write_text(spec.read_text() + extra)
    run = tmp_path / "run"
    found = qd.start(
        spec_file=spec,
        out=run,
        algorithm="auto",
        budget=4000,
        seed=4,
        backend=TWO,
        surrogate=qd.SurrogateOptions(inner_iterations=50, device="cpu"),
    )
    log = json.loads((run / "auto.json").read_text())
    batches = log["batches"]
    stints = [[b for b in batches if b["stint"] == s] for s in range(batches[-1]["stint"] + 1)]
    # Each arm measured once (SAS once it has data to train on), an arm that adapts over at
    # least WARMUP batches.
    firsts = [s for s in stints if s[0]["reason"] == "first measurement"]
    assert sorted(s[0]["arm"] for s in firsts) == sorted(ARMS) and firsts[0][0]["arm"] == "random"
    assert all(len(s) >= auto.WARMUP for s in firsts if s[0]["arm"] in auto.ADAPTING)
    for stint in stints:
        first = stint[0]
        rates = first["rates"]
        assert all((b["arm"], b["reason"], b["rates"]) == (first["arm"], first["reason"], rates) for b in stint)
        if first["reason"] == "best rate":
            assert rates[first["arm"]] == max(rates.values())
        elif first["reason"] != "first measurement":  # a losing arm, measured again
            learning = first["arm"] in auto.LEARNING and first["reason"].startswith("keeps learning")
            assert first["reason"].startswith("re-measure") or learning
            assert rates[first["arm"]] < max(rates.values())
    # A stint lasts at least its quantum, and measuring arms that did not come out best took at
    # most the allowed share of the run (give or take the stint that crossed it), as did
    # measuring a learning arm again.
    assert all(sum(b["seconds"] for b in stint) >= 0.2 for stint in stints[:-1])
    spent = sum(b["seconds"] for b in batches)
    for learning in (False, True):
        explored = [
            sum(b["seconds"] for b in s)
            for s, after in itertools.pairwise(stints[1:])
            if s[0]["reason"] != "best rate"
            and s[0]["reason"].startswith("keeps learning") == learning
            and after[0]["rates"][s[0]["arm"]] < max(after[0]["rates"].values())
        ]
        assert sum(explored) <= 0.6 * spent + max(explored, default=0.0)
        assert explored or learning
    assert sum(b["evaluations"] for b in batches) == found.state.evaluations == 4000

    # Where the time went is in run.json and progress.csv too.
    meta = json.loads((run / "run.json").read_text())
    assert meta["algorithm"] == "auto" and set(meta["auto"]["arms"]) == set(ARMS)
    assert sum(a["evaluations"] for a in meta["auto"]["arms"].values()) == 4000
    # with the schedule its SAS arm ran, not the spec's
    assert (meta["training"], meta["selection"], meta["inner_stall"]) == ("incremental", "gain", auto.STALL)
    sas = found.state.proposer.arms["sas"]
    assert (sas.training, sas.selection, sas.stall) == (meta["training"], meta["selection"], meta["inner_stall"])
    with open(run / "progress.csv", newline="") as handle:
        proposers = [row["proposer"] for row in csv.DictReader(handle)]
    assert proposers == [b["arm"] for b in batches]
    # SAS trained on what every arm simulated.
    proposer = found.state.proposer
    assert proposer.arms["sas"].trained > 100
    # CMA-MAE joined a search others began: its emitters started at elites, not at the centre.
    centre = algorithms.x0(found.domain)
    assert not any(np.allclose(e.x0, centre) for e in proposer.arms["cma_mae"].scheduler.emitters)


def test_cma_mae_starts_afresh_at_the_searchs_elites_when_it_comes_back(toy_spec, tmp_path, monkeypatch):
    # The choices are scripted (which arm wins is the test above's): CMA-MAE is measured, loses
    # to Random, is measured again, wins, comes back as the best after one stint of Random, and
    # again after ten.
    monkeypatch.setattr(auto, "MIN_STINT", 0.2)
    script = [
        ("random", "first measurement"),
        ("cma_mae", "first measurement"),
        ("random", "best rate"),
        ("cma_mae", "re-measure (best: random)"),
        ("cma_mae", "best rate"),
        ("random", "best rate"),
        ("cma_mae", "best rate"),
        *[("random", "best rate")] * 10,
        ("cma_mae", "best rate"),
    ]
    monkeypatch.setattr(auto.Auto, "_choose", lambda self, search: script[min(self.stint + 1, len(script) - 1)])
    starts = {}  # stint -> the CMA-MAE scheduler started for it
    start_cma_mae = auto.Auto._start_cma_mae

    def recording(self, domain):
        start_cma_mae(self, domain)
        starts[self.stint] = self.arms["cma_mae"].scheduler

    monkeypatch.setattr(auto.Auto, "_start_cma_mae", recording)
    spec = toy_spec("time_limit: 10.0\n", "time_limit: 10.0\n  params: {delay: 0.002}\n")
    spec.write_text(spec.read_text() + "  emitter: {emitters: 4, batch_size: 25}\n")
    found = qd.start(spec_file=spec, out=tmp_path / "run", algorithm="auto", budget=8000, seed=1, backend=TWO)
    batches = json.loads((tmp_path / "run" / "auto.json").read_text())["batches"]
    assert [b["stint"] for b in batches if b["arm"] == "cma_mae"][-1] > 18  # it went on as the best
    # Started at its first measurement, its second and its comeback after a long pause (ten stints
    # against PATIENCE times its last); not when it went straight on or came back after one stint.
    assert sorted(starts) == [1, 3, 17] and found.state.proposer.arms["cma_mae"].scheduler is starts[17]
    first, again, back = ([e.x0 for e in starts[s].emitters] for s in (1, 3, 17))
    assert not any(np.allclose(a, b) for a in first for b in again)
    assert not any(np.allclose(a, b) for a in again for b in back)


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
    # Exploring may take 8 % of a 10-second run: less than any other arm's first stint.
    assert {b["arm"] for b in after} == {"random"}
    indices = sorted(r.index for r in RunDirectory.open(run).evaluations())
    assert indices == list(range(len(indices)))
    assert "auto" in (run / "report" / "index.html").read_text()


def test_the_runs_first_stint_scores_only_until_its_arm_has_another(toy_spec):
    # Random's first stint has no pace before it; counted beside a later stint, its gain against
    # no expected gain would make Random look several times the pace.
    proposer = auto.Auto(load_domain(toy_spec()), seed=0, options=qd.SurrogateOptions())

    def batch(number: int, stint: int, arm: str, gain: float, pace: float) -> auto.Batch:
        return auto.Batch(
            batch=number, stint=stint, arm=arm, reason="", evaluations=10, seconds=1.0, gain=gain, pace=pace, rates={}
        )

    proposer.history = [batch(1, 0, "random", 1000.0, 0.0)]
    assert proposer.score("random") == 1.0
    proposer.history += [batch(2, 1, "map_elites", 500.0, 1000.0), batch(3, 2, "random", 400.0, 500.0)]
    assert proposer.score("random") == pytest.approx(400.0 / 500.0)


def test_only_an_arm_that_adapts_is_warmed_up_over_several_batches(toy_spec):
    # Where a Random batch takes 40 s (collaboration on a slow machine), three of them were 40 %
    # of a 5-minute run, and MAP-Elites' three-batch first measurement did not fit the share of
    # it that exploring may take. Their batches depend on the archive only, SAS's on the data;
    # CMA-ES adapts.
    proposer = auto.Auto(load_domain(toy_spec()), seed=0, options=qd.SurrogateOptions())
    proposer.history = [
        auto.Batch(batch=1, stint=0, arm="random", reason="", evaluations=100, seconds=40.0, gain=1.0, rates={})
    ]
    proposer.spent, proposer.stint_batches, proposer.stint_seconds = 40.0, 1, 40.0
    search = SimpleNamespace(seconds_left=math.inf)
    for arm in ARMS:
        proposer.choice, proposer.reason = arm, "first measurement"
        assert proposer._continues(search) == (arm == "cma_mae")
    batch = {arm: proposer.arms[arm].batch_size for arm in ARMS[:-1]}
    assert proposer._expected_seconds("map_elites") == pytest.approx(batch["map_elites"] * 0.4)
    assert proposer._expected_seconds("cma_mae") == pytest.approx(auto.WARMUP * batch["cma_mae"] * 0.4)


@pytest.mark.parametrize(
    ("setting", "option", "share"),
    [
        ("", None, 0.2),  # the specs' default
        ("  surrogate: {time_share: 0.25}\n", None, 0.25),
        ("  surrogate: {time_share: 0.25}\n", 0.5, 0.5),
        ("  surrogate: {time_share: 1}\n", None, auto.SHARE),  # the paper's specs never cut; auto does
    ],
)
def test_sas_in_auto_keeps_the_surrogate_to_its_time_share_of_what_simulating_a_batch_takes(
    toy_spec, setting, option, share
):
    spec = toy_spec()
    spec.write_text(spec.read_text() + setting)
    proposer = auto.Auto(load_domain(spec), seed=0, options=qd.SurrogateOptions(time_share=option))
    # Random simulated 100 scenarios in 4 s: a first SAS batch of 100 should take as long.
    proposer.history = [
        auto.Batch(batch=1, stint=0, arm="random", reason="", evaluations=100, seconds=4.0, gain=1.0, rates={})
    ]
    proposer.spent = 4.0
    assert proposer.arms["sas"]._seconds(proposer._seconds_per_evaluation()) == pytest.approx(4.0 * share / (1 - share))
    assert proposer._expected_seconds("sas") == pytest.approx(4.0 / (1 - share))


def test_arms_never_measured_are_measured_the_cheapest_first_stint_first(toy_spec, monkeypatch):
    # CMA-MAE's first stint is three of its batches of 8 x 37; SAS's one of 100 and the
    # surrogate's share: SAS comes first, once there are data to train it on.
    monkeypatch.setattr(auto, "EXPLORE", 1.0)
    spec = toy_spec()
    spec.write_text(spec.read_text() + "  emitter: {emitters: 8, batch_size: 37}\n")
    proposer = auto.Auto(load_domain(spec), seed=0, options=qd.SurrogateOptions())
    proposer.history = [
        auto.Batch(batch=1, stint=0, arm="random", reason="", evaluations=100, seconds=4.0, gain=1.0, rates={}),
        auto.Batch(batch=2, stint=1, arm="map_elites", reason="", evaluations=100, seconds=4.0, gain=1.0, rates={}),
    ]
    proposer.spent = 8.0
    assert proposer._expected_seconds("sas") < proposer._expected_seconds("cma_mae")
    assert proposer._choose(SimpleNamespace(seconds_left=math.inf, evaluated=200)) == ("sas", "first measurement")
    assert proposer._choose(SimpleNamespace(seconds_left=math.inf, evaluated=99)) == ("cma_mae", "first measurement")


def test_the_seconds_before_the_limit_that_a_sas_batch_would_not_fit_go_to_the_best_model_free_arm(
    toy_spec, monkeypatch
):
    # SAS's batch cannot be cut, and one that the limit cuts was simulated for nothing: a
    # 5-minute collaboration run ended at 294 s, its last 6 s spent on an inner loop.
    monkeypatch.setattr(auto, "EXPLORE", 0.0)  # nothing measured but the best
    proposer = auto.Auto(load_domain(toy_spec()), seed=0, options=qd.SurrogateOptions())

    def stint(number: int, arm: str, seconds: float, gain: float) -> auto.Batch:
        return auto.Batch(
            batch=number + 1, stint=number, arm=arm, reason="", evaluations=10, seconds=seconds, gain=gain,
            pace=100.0 if number else 0.0, rates={"random": 0.8, "map_elites": 0.9, "sas": 2.0},
        )  # fmt: skip

    proposer.history = [
        stint(0, "random", 10.0, 1000.0),
        stint(1, "random", 10.0, 800.0),
        stint(2, "map_elites", 10.0, 900.0),
        stint(3, "sas", 15.0, 3000.0),
    ]
    proposer.spent = 1000.0  # a long run: the pace after a stint not yet known
    assert [proposer.score(arm) for arm in ("random", "map_elites", "sas")] == pytest.approx([0.8, 0.9, 2.0])
    assert proposer._choose(SimpleNamespace(seconds_left=15.0, evaluated=400)) == ("sas", "best rate")
    assert proposer._choose(SimpleNamespace(seconds_left=14.0, evaluated=400)) == (
        "map_elites", "best rate in the time left"
    )  # fmt: skip
    # Such a stint is the best arm's that fits: not a measurement, not counted as exploring.
    explored = proposer._explored()
    proposer.history.append(replace(stint(4, "map_elites", 14.0, 700.0), reason="best rate in the time left"))
    assert proposer._explored() == explored


def test_sas_is_scored_by_its_stints_on_comparable_data_as_its_surrogate_learns_from_every_evaluation(toy_spec):
    # On collaboration SAS's first stint, on 120 evaluations, gained 0.37 of the pace and a later
    # one 1.02; scored over both, SAS stayed below MAP-Elites for the rest of the run. Scored by
    # its latest alone, one bad batch among good ones handed the lead back for minutes.
    proposer = auto.Auto(load_domain(toy_spec()), seed=0, options=qd.SurrogateOptions())

    def stint(number: int, arm: str, gain: float) -> auto.Batch:
        return auto.Batch(
            batch=number + 1, stint=number, arm=arm, reason="", evaluations=10, seconds=1.0, gain=gain, pace=100.0,
            rates={},
        )  # fmt: skip

    proposer.history = [
        stint(0, "random", 100.0),
        *(stint(n, arm, gain) for n, (arm, gain) in enumerate([("sas", 30.0), ("map_elites", 30.0)], start=1)),
        *(stint(n, arm, 100.0) for n, arm in enumerate(["random"] * 3 + ["sas", "map_elites"], start=3)),
    ]
    # Every later stint kept the pace: SAS's first (begun on 10 evaluations, under half the 60 its
    # latest began on) no longer scores it, MAP-Elites scores its last two.
    assert proposer.score("sas") == pytest.approx(1.0)
    assert proposer.score("map_elites") == pytest.approx(130.0 / 200.0)
    assert proposer.rate("sas") == pytest.approx(100.0)
    # A bad batch on comparable data (begun on 80) counts beside the good one, not alone.
    proposer.history.append(stint(8, "sas", 40.0))
    assert proposer.score("sas") == pytest.approx(140.0 / 200.0)
    assert proposer.rate("sas") == pytest.approx(70.0)


def test_a_measurement_that_made_its_arm_the_best_is_not_counted_as_exploring(toy_spec):
    # Counted, a noisy re-measurement that won spent the exploring share on the winner, and the
    # arm it displaced could no longer be measured again (collaboration: Random ran the last
    # two minutes alone).
    proposer = auto.Auto(load_domain(toy_spec()), seed=0, options=qd.SurrogateOptions())

    def stint(number: int, arm: str, reason: str, rates: dict[str, float]) -> auto.Batch:
        return auto.Batch(
            batch=number + 1, stint=number, arm=arm, reason=reason, evaluations=10, seconds=2.0, gain=1.0,
            pace=1.0, rates=rates,
        )  # fmt: skip

    proposer.history = [
        stint(0, "random", "first measurement", {}),
        stint(1, "map_elites", "first measurement", {"random": 1.0}),  # won: map_elites best next
        stint(2, "map_elites", "best rate", {"random": 1.0, "map_elites": 1.5}),
        stint(3, "random", "re-measure (best: map_elites)", {"random": 1.0, "map_elites": 1.2}),  # lost
        stint(4, "map_elites", "best rate", {"random": 0.8, "map_elites": 1.2}),
        stint(5, "random", "re-measure (best: map_elites)", {"random": 0.8, "map_elites": 0.9}),  # won
        stint(6, "random", "best rate", {"random": 1.1, "map_elites": 0.9}),
    ]
    assert proposer._explored() == 2.0
    # The last stint is judged by the scores now: random's re-measurement, if it is the last.
    proposer.history = proposer.history[:-1]
    won = proposer.score("random") >= proposer.score("map_elites")
    assert proposer._explored() == (2.0 if won else 4.0)


def test_a_learning_arm_not_far_behind_is_measured_again_from_a_share_of_its_own(toy_spec, monkeypatch):
    # On collaboration SAS gains half the pace in its first minutes and passes MAP-Elites after
    # five: a losing SAS is measured again as it learns, while it is not far behind, however much
    # of the exploring share the other arms took.
    proposer = auto.Auto(load_domain(toy_spec()), seed=0, options=qd.SurrogateOptions())

    def stint(number: int, arm: str, reason: str, seconds: float, gain: float, rates: dict) -> auto.Batch:
        return auto.Batch(
            batch=number + 1, stint=number, arm=arm, reason=reason, evaluations=10, seconds=seconds, gain=gain,
            pace=100.0 if number else 0.0, rates=rates,
        )  # fmt: skip

    def history(sas_gain: float) -> list[auto.Batch]:
        scores = {"random": 1.0, "cma_mae": 0.8, "sas": 0.5, "map_elites": 1.2}  # each at the next's start
        return [
            stint(0, "random", "first measurement", 10.0, 1000.0, {}),
            stint(1, "cma_mae", "first measurement", 10.0, 800.0, dict(list(scores.items())[:1])),
            stint(2, "sas", "first measurement", 5.0, sas_gain, dict(list(scores.items())[:2])),
            stint(3, "map_elites", "first measurement", 10.0, 1200.0, dict(list(scores.items())[:3])),
            stint(4, "map_elites", "best rate", 10.0, 1200.0, scores),
        ]

    forever = SimpleNamespace(seconds_left=math.inf, evaluated=1000)
    proposer.spent = 1000.0  # a long run: stints of 30 s, and the pace after a stint not yet known
    # SAS at 0.5 of the pace, MAP-Elites best at 1.2: the others have had 4 times SAS's stint.
    proposer.history = history(250.0)
    assert proposer.score("sas") == pytest.approx(0.5) and proposer.score("map_elites") == pytest.approx(1.2)
    # While its share of the time cuts every inner loop short of its stall, more data cannot
    # lift it (teleoperation): a losing arm like any other.
    sas = proposer.arms["sas"]
    sas.fits = [{"inner_iterations": sas.stall - 1}] * 3
    assert proposer._choose(forever) == ("sas", "re-measure (best: map_elites)")
    sas.fits[1] = {"inner_iterations": sas.stall}
    assert proposer._choose(forever) == ("sas", "keeps learning (best: map_elites)")
    # Its first round pays for the warm-up: it counts for nothing, either way.
    sas.fits = [{"inner_iterations": sas.stall}, {"inner_iterations": sas.stall - 1}]
    assert proposer._choose(forever) == ("sas", "re-measure (best: map_elites)")
    sas.fits = [{"inner_iterations": 1}]
    assert proposer._choose(forever) == ("sas", "keeps learning (best: map_elites)")
    # Far behind (under FLOOR of the best), it is a losing arm like any other, from the exploring share.
    proposer.history = history(100.0)
    assert proposer._choose(forever) == ("sas", "re-measure (best: map_elites)")
    # Once exploring took its share, only the learning arm is measured again, while it is not far behind.
    monkeypatch.setattr(auto, "EXPLORE", 0.04)
    assert proposer._choose(forever) == ("map_elites", "best rate")
    proposer.history = history(250.0)
    assert proposer._choose(forever) == ("sas", "keeps learning (best: map_elites)")
    # A learning stint that did not come out best counts in its own share, not the exploring one.
    rates = {"random": 1.0, "cma_mae": 0.8, "sas": 0.4, "map_elites": 1.2}
    proposer.history += [
        stint(5, "sas", "keeps learning (best: map_elites)", 5.0, 200.0, rates),
        stint(6, "map_elites", "best rate", 10.0, 1200.0, rates),
    ]
    assert proposer._explored(learning=True) == 5.0 and proposer._explored() == 15.0
