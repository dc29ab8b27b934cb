"""The nearest passing scenario to a failure: what would have had to differ for it not to fail.

Distances are measured in theta normalised by the parameters' bounds, so metres and seconds
weigh alike. The search, with the failure's seed and a bounded number of simulations:

1. one parameter at a time (a ``size: n`` group moves as one): toward its nominal value, and to
   each end of its bounds; where one of them passes, bisect back toward the failure to the
   smallest change of that parameter alone that still passes;
2. all parameters together along the segment to the nominal scenario, when it passes, bisected
   the same way.

The nearest passing candidate wins. A counterfactual is only as near as this search finds: it is
an upper bound on the distance to the failure's boundary, found cheaply, not the exact nearest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hritest.domain import Domain
from hritest.errors import HritestError
from hritest.evaluate import evaluate
from hritest.records import Evaluation

BUDGET = 60  # simulations, by default
BISECTIONS = 4  # halvings toward the failure of each passing move


class CounterfactualError(HritestError):
    """A scenario that is no failure, or one without a passing scenario within reach."""


@dataclass(frozen=True, kw_only=True)
class Counterfactual:
    """A failure and the nearest passing scenario found, both evaluated with the failure's seed."""

    failure_theta: np.ndarray
    failure: Evaluation
    theta: np.ndarray
    passing: Evaluation
    distance: float  # in theta normalised by the bounds
    changed: tuple[str, ...]  # the parameters that differ
    evaluations: int


def counterfactual(domain: Domain, theta: np.ndarray, *, seed: int, budget: int = BUDGET) -> Counterfactual:
    """The nearest passing scenario to the failing ``theta`` that the search finds.

    Raises:
        CounterfactualError: ``theta`` is not a failure, or no passing scenario was found.
    """
    theta = np.asarray(theta, dtype=float)
    search = _Search(domain=domain, seed=seed, budget=budget, origin=theta)
    failure = search.evaluate(theta)
    if not (failure.ok and failure.failure):
        raise CounterfactualError(
            f"the scenario is not a failure ({failure.status}, objective {failure.objective:.4g})"
        )
    nominal = np.asarray(domain.nominal, dtype=float)
    lower, upper = domain.space.lower, domain.space.upper
    for part in (slot.part for slot in domain.space.slots):
        for target in (nominal, lower, upper):
            moved = theta.copy()
            moved[part] = target[part]
            if search.passes(moved):
                search.bisect(moved)
    if search.passes(nominal):
        search.bisect(nominal)
    if search.best is None:
        raise CounterfactualError(
            f"no passing scenario found in {search.used} simulations: moving any one parameter to its nominal "
            "value or either bound, or all to nominal, still fails"
        )
    best, evaluation = search.best
    changed = tuple(s.name for s in domain.space.slots if not np.allclose(best[s.part], theta[s.part]))
    return Counterfactual(
        failure_theta=theta,
        failure=failure,
        theta=best,
        passing=evaluation,
        distance=search.distance(best),
        changed=changed,
        evaluations=search.used,
    )


@dataclass
class _Search:
    domain: Domain
    seed: int
    budget: int
    origin: np.ndarray
    used: int = 0
    best: tuple[np.ndarray, Evaluation] | None = None

    def distance(self, theta: np.ndarray) -> float:
        width = np.where(
            self.domain.space.upper > self.domain.space.lower, self.domain.space.upper - self.domain.space.lower, 1.0
        )
        return float(np.linalg.norm((theta - self.origin) / width))

    def evaluate(self, theta: np.ndarray) -> Evaluation:
        self.used += 1
        return evaluate(self.domain, theta, seed=self.seed)

    def passes(self, theta: np.ndarray) -> bool:
        """Simulates ``theta`` (unless the budget is spent or it is no nearer than the best); keeps a pass."""
        if self.used >= self.budget or np.array_equal(theta, self.origin):
            return False
        if self.best is not None and self.distance(theta) >= self.distance(self.best[0]):
            return False
        evaluation = self.evaluate(theta)
        if evaluation.ok and not evaluation.failure:
            self.best = (theta, evaluation)
            return True
        return False

    def bisect(self, passing: np.ndarray) -> None:
        """Moves a passing ``theta`` back toward the failure while it still passes."""
        near, far = 0.0, 1.0  # fractions of the way from the failure: far passes, near fails
        for _ in range(BISECTIONS):
            middle = (near + far) / 2
            if self.passes(self.origin + middle * (passing - self.origin)):
                far = middle
            else:
                near = middle


__all__ = ["BUDGET", "Counterfactual", "CounterfactualError", "counterfactual"]
