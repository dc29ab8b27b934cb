"""Re-simulate a stored scenario and check that it still gives the outcome the run recorded.

A replay evaluates the stored *raw* theta (what the search proposed) with the stored seed, so
repair, simulation and metrics all run again, and compares the new outcome with the stored one:
the status and the failure verdict exactly, the objective and every measure within an absolute
tolerance (:data:`TOLERANCE` by default). For a scenario given by hand there is nothing stored,
so the scenario is simulated twice and the second outcome is compared with the first: a
determinism check.

:func:`compare` is pure; the rest reads run directories.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hritest.domain import Domain, load_domain
from hritest.errors import HritestError
from hritest.evaluate import evaluate_with_rollout
from hritest.protocols import Rollout
from hritest.records import Evaluation, EvaluationRecord, clauses_text, rank_failures, scenario_digest
from hritest.rundir import RunDirectory

TOLERANCE = 1e-6  # absolute, on the objective and on each measure


class UnknownFailureError(HritestError):
    """A failure id that the run directory does not hold."""


class EmptyRunError(HritestError):
    """A run directory with no finished evaluation."""


@dataclass(frozen=True)
class Check:
    """One compared quantity: what was stored, what the replay gave, and whether they agree."""

    name: str
    stored: Any
    replayed: Any
    ok: bool


@dataclass(frozen=True)
class Replay:
    """A re-simulated scenario: its new evaluation and rollout, and how it compares."""

    domain: Domain
    evaluation: Evaluation
    rollout: Rollout | None
    digest: str
    checks: tuple[Check, ...]
    against: str  # what the outcome was compared with, in words
    tolerance: float
    reference: str = "stored"  # a short name for what was compared with (a table heading)
    stored_why: str = ""  # the failure clauses that held when it was stored, as clauses_text gives them

    @property
    def why(self) -> str:
        """Which failure clauses held then and now: ``stored: fails objective >= 8 (objective=10)``."""
        now = clauses_text(self.evaluation.fired) if self.evaluation.failure else ""
        lines = [f"stored:   fails {self.stored_why}"] if self.stored_why else []
        return "\n".join([*lines, f"replayed: fails {now}" if now else "replayed: not a failure"])

    @property
    def matches(self) -> bool:
        return all(check.ok for check in self.checks)


def outcome_of(evaluation: Evaluation) -> dict[str, Any]:
    """The fields of an evaluation that a replay compares, as a run directory stores them."""
    return {
        "status": evaluation.status,
        "failure": evaluation.failure,
        "objective": _finite(evaluation.objective),
        "measures": [_finite(v) for v in np.asarray(evaluation.measures, dtype=float)],
    }


def compare(
    stored: Mapping[str, Any],
    replayed: Mapping[str, Any],
    measure_names: Sequence[str],
    *,
    tolerance: float = TOLERANCE,
) -> tuple[Check, ...]:
    """Compares two outcomes (as :func:`outcome_of` gives them): status and failure exactly,
    objective and measures within ``tolerance`` (absolute; ``None`` stands for not finite)."""
    checks = [
        Check("status", stored.get("status"), replayed["status"], stored.get("status") == replayed["status"]),
        Check(
            "failure",
            stored.get("failure"),
            replayed["failure"],
            bool(stored.get("failure")) == bool(replayed["failure"]),
        ),
        Check(
            "objective",
            stored.get("objective"),
            replayed["objective"],
            _close(stored.get("objective"), replayed["objective"], tolerance),
        ),
    ]
    old = list(stored.get("measures") or [])
    new = list(replayed["measures"])
    for i, name in enumerate(measure_names):
        a = old[i] if i < len(old) else None
        b = new[i] if i < len(new) else None
        checks.append(Check(name, a, b, _close(a, b, tolerance) and (i < len(old)) == (i < len(new))))
    return tuple(checks)


def _close(a: float | None, b: float | None, tolerance: float) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return abs(float(a) - float(b)) <= tolerance


def _finite(value: float) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None


# --- run directories ---------------------------------------------------------------------------


def run_domain(run: RunDirectory, *, trust: bool = False) -> Domain:
    """The run's own copy of its spec, compiled with plugin paths relative to the original spec.

    Raises:
        RunDirectoryError: plugin files from outside the user's project in a run another user
            wrote, unless the caller trusts the run (see :meth:`RunDirectory.plugin_base`).
    """
    return load_domain(run.path / "spec.yaml", base=run.plugin_base(trust=trust))


def failure_ids(run: RunDirectory) -> list[int]:
    """The ids of the run's reported failures (``failures.yaml``, worst first).

    A run killed before its first summary has no ``failures.yaml``; then every evaluation
    flagged as a failure counts.
    """
    path = run.path / "failures.yaml"
    if path.is_file():
        data = yaml.safe_load(path.read_text()) or {}
        return [int(f["id"]) for f in data.get("failures") or []]
    return [r.index for r in rank_failures(run.iter_evaluations())]


def stored_failure(run: RunDirectory, failure_id: int) -> EvaluationRecord:
    """The evaluation record of failure ``failure_id``.

    Raises:
        EmptyRunError: the run has no evaluations.
        UnknownFailureError: no such failure; the message lists the ids there are.
    """
    if not run.has_evaluations():
        raise EmptyRunError(f"{run.path} has no evaluations yet; there is nothing to replay")
    ids = failure_ids(run)
    found = run.evaluations_of([failure_id]) if failure_id in ids else {}
    if failure_id not in found:
        listed = ", ".join(map(str, ids[:50])) + (f", ... ({len(ids)} in all)" if len(ids) > 50 else "")
        known = f"its failures (worst first) are: {listed}" if ids else "it has no failures"
        raise UnknownFailureError(f"{run.path} has no failure with id {failure_id}; {known}")
    return found[failure_id]


def replay_record(
    domain: Domain, record: EvaluationRecord, *, spec_digest: str, tolerance: float = TOLERANCE
) -> Replay:
    """Re-simulates a stored evaluation record (its raw ``theta`` and ``seed``) and compares."""
    replayed = replay_outcome(
        domain,
        theta=record.theta,
        seed=record.seed,
        stored=record.to_json(),
        against=f"evaluation {record.index} as stored in evaluations.jsonl",
        spec_digest=spec_digest,
        tolerance=tolerance,
    )
    return replace(replayed, stored_why=clauses_text(record.fired))


def replay_outcome(
    domain: Domain,
    *,
    theta: Sequence[float],
    seed: int,
    stored: Mapping[str, Any],
    against: str,
    spec_digest: str,
    tolerance: float = TOLERANCE,
) -> Replay:
    """Re-simulates raw ``theta`` with ``seed`` and compares with a ``stored`` outcome (status,
    failure, objective, measures as :func:`outcome_of` gives them); ``against`` says what that was."""
    evaluation, rollout = evaluate_with_rollout(domain, np.asarray(theta, dtype=float), seed=int(seed))
    checks = compare(stored, outcome_of(evaluation), [m.name for m in domain.measures], tolerance=tolerance)
    return Replay(
        domain=domain,
        evaluation=evaluation,
        rollout=rollout,
        digest=scenario_digest(spec_digest, evaluation.theta_repaired, evaluation.seed),
        checks=checks,
        against=against,
        tolerance=tolerance,
    )


def replay_failure(run_path: Path, failure_id: int, *, tolerance: float = TOLERANCE) -> Replay:
    """Re-simulates failure ``failure_id`` of the run at ``run_path`` and compares it with the record.

    Raises:
        RunDirectoryError, EmptyRunError, UnknownFailureError, SpecError: bad input.
    """
    run = RunDirectory.open(run_path)
    record = stored_failure(run, failure_id)
    return replay_record(run_domain(run), record, spec_digest=run.meta["spec_digest"], tolerance=tolerance)


def replay_theta(
    domain: Domain, theta: np.ndarray, *, seed: int, spec_digest: str, tolerance: float = TOLERANCE
) -> Replay:
    """Simulates a scenario given by hand twice; the second run is checked against the first."""
    first, _ = evaluate_with_rollout(domain, theta, seed=seed)
    evaluation, rollout = evaluate_with_rollout(domain, theta, seed=seed)
    checks = compare(outcome_of(first), outcome_of(evaluation), [m.name for m in domain.measures], tolerance=tolerance)
    return Replay(
        domain=domain,
        evaluation=evaluation,
        rollout=rollout,
        digest=scenario_digest(spec_digest, evaluation.theta_repaired, seed),
        checks=checks,
        against="a first simulation of the same theta and seed (determinism)",
        tolerance=tolerance,
        reference="first run",
    )
