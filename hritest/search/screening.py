"""Which of SAS's proposals are worth their simulation, judged by what earlier ones gained.

SAS proposes one surrogate elite per block of the selection grid, and simulates them all. Once
the archive fills, most of them add nothing: on collaboration I (auto, after 25 minutes) the fifth
of the proposals that the surrogate predicted the lowest objective gained 0.4 QD-score per second
of simulation and the highest fifth 6.4, against 3.8 for all. The surrogate's predicted *cell* is
too rough to say which cell a proposal lands in (a tenth of the measure's range off, on
collaboration), but its predicted *objective* ranks the proposals by what they gain: the
elites they would have to beat are, by then, of high objective everywhere.

So a round simulates the proposals whose predicted objective gained the most per second in the
last rounds, as many as raise the round's rate: a proposal is worth its simulation when
what it is expected to gain per second is above what the round as a whole gains per second,
counting the surrogate's work, which a round pays however few scenarios it simulates. This is the
marginal value theorem of foraging: leave the patch when what it yields falls below the average
rate. Proposals are ranked by their predicted objective's bin among the last rounds'
(:data:`BINS` bins of equal count); the bins' rates are measured, not predicted, so a bin
that stops paying is dropped, and one below every bin measured is judged by the lowest
bin's rate: if that pays, it is simulated and measured in turn.
"""

from __future__ import annotations

import numpy as np

ROUNDS = 5  # the last rounds whose proposals' outcomes judge the next's
BINS = 5  # of the last rounds' proposals, by predicted objective
MIN_OUTCOMES = 100  # fewer measured proposals than this say too little: simulate everything


def worth_simulating(
    predicted: np.ndarray,
    *,
    outcomes: np.ndarray,
    overhead: float,
) -> np.ndarray:
    """Which of the proposals of ``predicted`` objective to simulate.

    Args:
        predicted: the proposals' predicted objective.
        outcomes: ``(n, 3)`` rows of earlier proposals: predicted objective, the QD-score its
            simulation added, and the seconds it took to simulate.
        overhead: what the round costs whatever it simulates (its surrogate work), in the same
            seconds as the outcomes'.

    Returns:
        A boolean mask over ``predicted``: the proposals in the bins that, taken best first, each
        gain more per second than the round with the bins before it and the overhead. Everything
        while the outcomes are fewer than :data:`MIN_OUTCOMES` or gained nothing.
    """
    predicted = np.asarray(predicted, dtype=float)
    everything = np.ones(len(predicted), bool)
    if len(outcomes) < MIN_OUTCOMES or len(predicted) == 0:
        return everything
    earlier, gain, seconds = np.asarray(outcomes, dtype=float).T
    if gain.sum() <= 0:
        return everything
    edges = np.quantile(earlier, np.linspace(0, 1, BINS + 1)[1:-1])
    of_outcome, of_proposal = np.searchsorted(edges, earlier), np.searchsorted(edges, predicted)
    bin_gain = np.bincount(of_outcome, weights=gain, minlength=BINS)
    bin_seconds = np.bincount(of_outcome, weights=seconds, minlength=BINS)
    bin_count = np.bincount(of_outcome, minlength=BINS)
    rate = bin_gain / np.maximum(bin_seconds, 1e-12)
    # Per proposal, its bin's mean gain and seconds; bins taken at their rate, best first.
    taken, total_gain, total_seconds = np.zeros(len(predicted), bool), 0.0, max(overhead, 0.0)
    for b in np.argsort(-rate, kind="stable"):
        members = of_proposal == b
        if not members.any() or bin_count[b] == 0:
            continue
        if total_gain > 0 and rate[b] <= total_gain / total_seconds:
            break
        taken |= members
        total_gain += members.sum() * bin_gain[b] / bin_count[b]
        total_seconds += members.sum() * bin_seconds[b] / bin_count[b]
    return taken
