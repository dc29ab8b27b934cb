import numpy as np

from hritest.search import screening


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
