import json

import numpy as np

from hritest import search as qd
from hritest.rundir import RunDirectory
from hritest.search import archives, screening


def outcomes(rates: list[float], *, per_bin: int = 40, seconds: float = 1.0) -> np.ndarray:
    """Earlier proposals in len(rates) bins of predicted objective 0.1, 0.2, ..., each gaining at its bin's rate."""
    rows = [(0.1 * (b + 1), rate * seconds, seconds) for b, rate in enumerate(rates) for _ in range(per_bin)]
    return np.array(rows)


def test_proposals_predicted_where_earlier_ones_gained_little_are_not_simulated():
    earlier = outcomes([0.1, 0.5, 3.0, 5.0, 6.0])
    predicted = np.array([0.1, 0.2, 0.3, 0.4, 0.5])
    keep = screening.worth_simulating(predicted, outcomes=earlier, overhead=3.0)
    # one each of the top three bins: 14 gained in 3 + 3 seconds, 2.3 a second; the next would gain 0.5
    assert keep.tolist() == [False, False, True, True, True]


def test_the_overhead_makes_more_of_them_worth_simulating():
    """A round pays its surrogate work however few it simulates: the costlier that work, the
    lower the rate a proposal must beat (the marginal value theorem)."""
    earlier = outcomes([1.0, 2.0, 3.0, 5.0, 6.0])
    predicted = np.repeat([0.1, 0.2, 0.3, 0.4, 0.5], 20)
    cheap = screening.worth_simulating(predicted, outcomes=earlier, overhead=0.0)
    costly = screening.worth_simulating(predicted, outcomes=earlier, overhead=1000.0)
    assert cheap.sum() == 20  # only the best bin beats itself
    assert costly.all()


def test_below_every_bin_measured_a_proposal_is_judged_by_the_lowest_bin():
    earlier = outcomes([4.0, 4.0, 4.0, 4.0, 4.0])
    assert screening.worth_simulating(np.array([-5.0, 0.3]), outcomes=earlier, overhead=1.0).all()


def test_everything_is_simulated_until_there_is_enough_to_judge_by_or_anything_gained():
    few = outcomes([0.0, 0.0, 0.0, 0.0, 9.0], per_bin=screening.MIN_OUTCOMES // 5 - 1)
    nothing = outcomes([0.0] * 5)
    predicted = np.array([0.1, 0.5])
    assert screening.worth_simulating(predicted, outcomes=few, overhead=0.0).all()
    assert screening.worth_simulating(predicted, outcomes=nothing, overhead=0.0).all()


def test_a_screening_sas_simulates_what_it_kept_and_measures_what_each_scenario_added(toy_spec, tmp_path):
    """The rounds' outcomes are the QD-score each simulated proposal added (replayed here one by
    one), and the rounds that screened proposals out simulated the rest. Scenarios of the toy
    domain that take 50 ms, against a small surrogate's work: worth screening."""
    spec = toy_spec("time_limit: 10.0\n", "time_limit: 10.0\n  params: {delay: 0.05}\n")
    surrogate = "{initial_evaluations: 40, inner_iterations: 20, epochs: 3, downsample_cells: [8, 8], time_share: 1}"
    spec.write_text(spec.read_text() + f"  surrogate: {surrogate}\n")
    found = qd.start(
        spec_file=spec,
        out=tmp_path / "run",
        algorithm="sas",
        budget=600,
        seed=0,
        backend=qd.Backend(workers=2, timeout=20),
        surrogate=qd.SurrogateOptions(device="cpu"),
    )
    sas = found.state.proposer
    assert sas.screen and json.loads((tmp_path / "run" / "run.json").read_text())["screen"] is True
    # Replayed in order into a fresh result archive, each scenario of the last told batch added
    # what the run measured (where no other scenario of its batch shares its cell).
    records = sorted(RunDirectory.open(tmp_path / "run").evaluations(), key=lambda r: r.index)
    archive = archives.result_archive(found.domain, seed=0)
    added = {}
    for r in records:
        if r.ok:
            before = archive.stats.qd_score
            archive.add([r.theta_repaired], [r.objective], [r.measures], evaluation=[r.index])
            added[r.index] = archive.stats.qd_score - before
    last = records[found.state.evaluations - len(sas.outcomes[-1]) : found.state.evaluations]
    cells = archive.index_of(np.array([r.measures for r in last]))
    alone = [i for i, c in enumerate(cells) if (cells == c).sum() == 1 and last[i].ok]
    assert alone and np.allclose(sas.outcomes[-1][alone, 1], [added[last[i].index] for i in alone])
    assert np.allclose(sas.outcomes[-1][:, 2], [r.seconds for r in last], atol=1e-6)  # stored to the microsecond
    # Something was screened out once there were outcomes to judge by, and what was kept was simulated.
    assert sum(fit["screened_out"] for fit in sas.fits) > 0
    sizes = np.diff([0] + [row.evaluations for row in found.state.progress])
    assert sizes[0] == 40 and sizes[1:-1].tolist() == [fit["proposed"] for fit in sas.fits][: len(sizes) - 2]
