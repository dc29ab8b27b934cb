"""Shrinking a failure: the simplest scenario that still fails the same way.

As Hypothesis shrinks a failing example, hritest moves a failing scenario's parameters toward
their nominal values (a parameter's ``nominal``, else its target's nominal value, else the
centre of its bounds: :attr:`hritest.domain.Domain.nominal`) for as long as the same clause of
the failure condition still holds. What is left away from nominal is what the failure needs.

The passes, each simulating its candidates with the failure's own seed:

1. every parameter to nominal at once (a failure of the nominal scenario needs nothing);
2. each parameter (a group of ``size: n`` components moves as one) to nominal alone;
3. each remaining one bisected toward nominal: the smallest fraction of its distance that keeps
   the failure, to :data:`BISECTIONS` halvings.

A candidate is kept only if its evaluation is ``ok`` and the clause holds, so a step never
trades the failure for another or for a crash, and no parameter ever moves away from nominal.
Every pass stops when the simulation budget is spent.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hritest.domain import Domain
from hritest.errors import HritestError
from hritest.evaluate import evaluate
from hritest.records import Evaluation
from hritest.replay import run_domain, stored_failure
from hritest.rundir import RunDirectory, atomic_write

BUDGET = 100  # simulations a shrink may spend, by default
BISECTIONS = 4  # halvings of each remaining parameter's distance to nominal
SAME = 1e-9  # a component this close to nominal is nominal


class ShrinkError(HritestError):
    """A scenario that cannot be shrunk: it does not fail, or not with the clause asked for."""


@dataclass(frozen=True, kw_only=True)
class Shrunk:
    """The outcome of :func:`shrink`: the shrunk scenario, its evaluation and what it cost."""

    original: np.ndarray
    theta: np.ndarray
    nominal: np.ndarray
    parameters: dict[str, slice]  # each spec parameter's components in theta
    clause: str
    evaluation: Evaluation
    evaluations: int
    steps: tuple[str, ...] = field(default=())

    def off_nominal(self, theta: np.ndarray) -> list[str]:
        """The parameters of ``theta`` (the original or the shrunk one) not at their nominal value."""
        return [name for name, part in self.parameters.items() if not _at(theta[part], self.nominal[part])]

    def to_json(self) -> dict[str, Any]:
        """What ``hritest shrink --json`` prints and ``<run>/shrunk/<id>.json`` holds."""
        matters = set(self.off_nominal(self.theta))
        return {
            "clause": self.clause,
            "theta": self.theta.tolist(),
            "original_theta": self.original.tolist(),
            "nominal_theta": self.nominal.tolist(),
            "evaluations": self.evaluations,
            "objective": self.evaluation.objective,
            "parameters": {
                name: {
                    "original": self.original[part].tolist(),
                    "shrunk": self.theta[part].tolist(),
                    "nominal": self.nominal[part].tolist(),
                    "matters": name in matters,
                }
                for name, part in self.parameters.items()
            },
            "steps": list(self.steps),
        }


def shrink(domain: Domain, theta: np.ndarray, *, seed: int, clause: str | None = None, budget: int = BUDGET) -> Shrunk:
    """Shrinks the failing scenario ``theta`` (evaluated with ``seed``) toward nominal.

    Args:
        clause: the failure clause to keep (its text, as :class:`hritest.records.Clause` gives
            it); default: the first clause that holds for ``theta``.
        budget: the most simulations to spend, the first (checking ``theta`` fails) included.

    Raises:
        ShrinkError: ``theta`` does not fail, or ``clause`` does not hold for it.
    """
    theta = np.asarray(theta, dtype=float)
    first = evaluate(domain, theta, seed=seed)
    fired = [c.text for c in first.fired]
    if not first.ok or not first.failure:
        raise ShrinkError(f"the scenario is not a failure ({first.status}, objective {first.objective:.4g})")
    if clause is None:
        clause = fired[0]
    elif clause not in fired:
        raise ShrinkError(f"the clause {clause!r} does not hold for this scenario; the ones that do: {fired}")
    state = _State(domain=domain, seed=seed, clause=clause, budget=budget, theta=theta, evaluation=first)
    nominal = np.asarray(domain.nominal, dtype=float)
    slices = {slot.name: slot.part for slot in domain.space.slots}
    state.try_(nominal.copy(), "every parameter nominal")
    for name, part in slices.items():
        if not _at(state.theta[part], nominal[part]):
            state.try_(_toward(state.theta, nominal, part, 0.0), f"{name} nominal")
    for name, part in slices.items():
        _bisect(state, nominal, part, name)
    return Shrunk(
        original=theta,
        theta=state.theta,
        nominal=nominal,
        parameters=slices,
        clause=clause,
        evaluation=state.evaluation,
        evaluations=state.used,
        steps=tuple(state.steps),
    )


def shrink_failure(
    run_path: Path, failure_id: int, *, clause: str | None = None, budget: int = BUDGET
) -> tuple[Shrunk, Path]:
    """Shrinks failure ``failure_id`` of a run (its stored raw theta and seed) and stores the
    result in ``<run>/shrunk/<id>.json``, which ``hritest promote --shrink`` reads.

    Raises:
        RunDirectoryError, EmptyRunError, UnknownFailureError, SpecError, ShrinkError: bad input.
    """
    run = RunDirectory.open(run_path)
    record = stored_failure(run, failure_id)
    result = shrink(run_domain(run), np.asarray(record.theta), seed=record.seed, clause=clause, budget=budget)
    path = run.path / "shrunk" / f"{failure_id}.json"
    path.parent.mkdir(exist_ok=True)
    atomic_write(path, json.dumps({"failure": failure_id, "seed": record.seed, **result.to_json()}, indent=1))
    return result, path


def _bisect(state: _State, nominal: np.ndarray, part: slice, name: str) -> None:
    """Halves the parameter's distance to nominal while the failure holds, then halves the step."""
    low, high = 0.0, 1.0  # fractions of the current distance: low fails to keep it, high keeps it
    start = state.theta.copy()
    for _ in range(BISECTIONS):
        if _at(start[part], nominal[part]) or state.spent:
            return
        middle = (low + high) / 2
        if state.try_(_toward(start, nominal, part, middle), f"{name} to {middle:.3g} of its distance"):
            high = middle
        else:
            low = middle


def _toward(theta: np.ndarray, nominal: np.ndarray, part: slice, fraction: float) -> np.ndarray:
    """``theta`` with the components of ``part`` at ``fraction`` of their distance from nominal."""
    moved = theta.copy()
    moved[part] = nominal[part] + fraction * (theta[part] - nominal[part])
    return moved


def _at(values: np.ndarray, nominal: np.ndarray) -> bool:
    return bool(np.all(np.abs(np.asarray(values) - np.asarray(nominal)) <= SAME))


@dataclass
class _State:
    """The shrink so far: the smallest failing theta found, and the simulations spent."""

    domain: Domain
    seed: int
    clause: str
    budget: int
    theta: np.ndarray
    evaluation: Evaluation
    used: int = 1
    steps: list[str] = field(default_factory=list)

    @property
    def spent(self) -> bool:
        return self.used >= self.budget

    def try_(self, candidate: np.ndarray, step: str) -> bool:
        """Simulates ``candidate``; keeps it if the clause still holds. False once the budget is spent."""
        if self.spent or np.array_equal(candidate, self.theta):
            return False
        self.used += 1
        evaluation = evaluate(self.domain, candidate, seed=self.seed)
        if evaluation.ok and any(c.text == self.clause for c in evaluation.fired):
            self.theta, self.evaluation = candidate, evaluation
            self.steps.append(step)
            return True
        return False


__all__ = ["BUDGET", "ShrinkError", "Shrunk", "shrink", "shrink_failure"]
