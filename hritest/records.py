"""The records that cross a stage boundary: an evaluation's status, the failure clauses that held,
and the evaluation itself, with the JSON form the run directory, the corpus and ``--json`` share.

Every status an evaluation can end with is a :class:`Status`; nothing compares status strings.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np

# The largest seed of a search or an evaluation: torch's generators take unsigned 64-bit seeds,
# and hritest adds small offsets to a run's seed for its networks; half the range leaves them room.
MAX_SEED = 2**63 - 1


class Status(StrEnum):
    """How an evaluation ended. Only ``ok`` has an objective; the others say why not."""

    OK = "ok"
    PLUGIN_ERROR = "plugin_error"  # a plugin raised, or its rollout broke the contract
    METRIC_ERROR = "metric_error"  # a declared metric missing, or an expression that cannot be computed
    NAN = "nan"  # the objective or a measure is not a finite number
    TIMEOUT = "timeout"  # past the per-evaluation time limit; the worker was stopped
    CRASHED = "crashed"  # the worker process died, or hritest failed around the plugin
    REPAIR_INFEASIBLE = "repair_infeasible"  # no valid scenario near theta
    REPAIR_TIMEOUT = "repair_timeout"  # the repair program ran out of time
    REPAIR_ERROR = "repair_error"  # the repair solver failed

    @classmethod
    def parse(cls, value: str) -> Status:
        """A status read back from a file; an unknown one is an error naming the known ones."""
        try:
            return cls(value)
        except ValueError:
            known = ", ".join(s.value for s in cls)
            raise ValueError(f"unknown evaluation status {value!r}; known: {known}") from None


@dataclass(frozen=True, kw_only=True)
class Clause:
    """One operand of the failure condition (``objective >= 15`` of ``objective >= 15 or ...``), whether
    it held, and the values of the names it reads: what a user needs to see *why* a scenario failed."""

    text: str
    holds: bool
    values: Mapping[str, float] = field(default_factory=dict)

    def __str__(self) -> str:
        shown = ", ".join(f"{name}={_short(value)}" for name, value in self.values.items())
        return f"{self.text} ({shown})" if shown else self.text

    def to_json(self) -> dict[str, Any]:
        return {"clause": self.text, "holds": self.holds, "values": {k: float(v) for k, v in self.values.items()}}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Clause:
        return cls(text=str(data["clause"]), holds=bool(data["holds"]), values=dict(data.get("values", {})))


@dataclass(frozen=True, kw_only=True)
class Evaluation:
    """The outcome of one scenario.

    ``objective`` is the raw objective (what the result archive and the report see);
    ``search_objective`` subtracts the weighted repair cost (what the search archive sees).
    ``clauses`` are the failure condition's clauses with their values (empty when not ``ok``).
    """

    theta: np.ndarray
    theta_repaired: np.ndarray
    repair_cost: float
    regions: dict[str, str | None]
    seed: int
    status: Status = Status.OK
    message: str = ""
    objective: float = math.nan
    search_objective: float = math.nan
    measures: np.ndarray = field(default_factory=lambda: np.array([]))
    metrics: dict[str, float] = field(default_factory=dict)
    occupancy: np.ndarray | None = None
    failure: bool = False
    clauses: tuple[Clause, ...] = ()
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        return self.status is Status.OK

    @property
    def fired(self) -> tuple[Clause, ...]:
        """The clauses that held: why this scenario is a failure (empty if it is not)."""
        return tuple(c for c in self.clauses if c.holds)


@dataclass(frozen=True, kw_only=True)
class EvaluationRecord:
    """One line of a run's ``evaluations.jsonl``: an :class:`Evaluation` without its grids (stored
    apart), with its place in the search. Read back with :meth:`from_json`, which also reads the
    lines of run directories written before clauses were recorded.

    Numbers that are not finite (an evaluation that never produced them) are NaN here and
    ``null`` in JSON.
    """

    index: int
    batch: int
    status: Status
    failure: bool
    objective: float
    search_objective: float
    measures: tuple[float, ...]
    repair_cost: float
    regions: Mapping[str, str | None]
    theta: tuple[float, ...]
    theta_repaired: tuple[float, ...]
    metrics: Mapping[str, float]
    seed: int
    seconds: float
    message: str = ""
    clauses: tuple[Clause, ...] = ()

    @property
    def ok(self) -> bool:
        return self.status is Status.OK

    @property
    def fired(self) -> tuple[Clause, ...]:
        """The failure condition's clauses that held."""
        return tuple(c for c in self.clauses if c.holds)

    @classmethod
    def of(cls, evaluation: Evaluation, *, index: int, batch: int) -> EvaluationRecord:
        return cls(
            index=index,
            batch=batch,
            status=evaluation.status,
            failure=evaluation.failure,
            objective=float(evaluation.objective),
            search_objective=float(evaluation.search_objective),
            measures=tuple(float(v) for v in evaluation.measures),
            repair_cost=float(evaluation.repair_cost),
            regions=dict(evaluation.regions),
            theta=tuple(float(v) for v in np.asarray(evaluation.theta).ravel()),
            theta_repaired=tuple(float(v) for v in np.asarray(evaluation.theta_repaired).ravel()),
            metrics={k: float(v) for k, v in evaluation.metrics.items()},
            seed=int(evaluation.seed),
            seconds=float(evaluation.seconds),
            message=evaluation.message,
            clauses=evaluation.clauses,
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "index": self.index,
            "batch": self.batch,
            "status": self.status.value,
            "failure": self.failure,
            "objective": _number(self.objective),
            "search_objective": _number(self.search_objective),
            "measures": [_number(v) for v in self.measures],
            "repair_cost": _number(self.repair_cost),
            "regions": dict(self.regions),
            "theta": list(self.theta),
            "theta_repaired": list(self.theta_repaired),
            "metrics": {k: _number(v) for k, v in self.metrics.items()},
            "seed": self.seed,
            "seconds": round(self.seconds, 6),
            "message": self.message,
            "clauses": [c.to_json() for c in self.clauses],
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> EvaluationRecord:
        """Raises KeyError, ValueError or TypeError on a line that is not a record."""
        return cls(
            index=int(data["index"]),
            batch=int(data.get("batch", 0)),
            status=Status.parse(data["status"]),
            failure=bool(data["failure"]),
            objective=_float(data["objective"]),
            search_objective=_float(data.get("search_objective", data["objective"])),
            measures=tuple(_float(v) for v in data["measures"]),
            repair_cost=_float(data.get("repair_cost", 0.0)),
            regions=dict(data.get("regions") or {}),
            theta=tuple(float(v) for v in data["theta"]),
            theta_repaired=tuple(float(v) for v in data["theta_repaired"]),
            metrics={k: _float(v) for k, v in (data.get("metrics") or {}).items()},
            seed=int(data["seed"]),
            seconds=float(data.get("seconds", 0.0)),
            message=str(data.get("message", "")),
            clauses=tuple(Clause.from_json(c) for c in data.get("clauses", ())),
        )


def rank_failures(records: Iterable[EvaluationRecord]) -> list[EvaluationRecord]:
    """Failures worst first: the one order the report, ``failures.yaml``, replay and promote share.

    Highest objective first; ties by the evaluation's index, so two runs of a seed agree.
    """
    found = [r for r in records if r.failure]
    return sorted(found, key=lambda r: (-_or(r.objective, -math.inf), r.index))


def worst_of_each_clause(failures: Sequence[EvaluationRecord]) -> dict[str, EvaluationRecord]:
    """For each clause that fired in some failure, the worst failure it fired in (``failures``
    ranked by :func:`rank_failures`): a safety clause is represented even when its failures are
    not among the highest objectives."""
    worst: dict[str, EvaluationRecord] = {}
    for record in failures:
        for clause in record.fired:
            worst.setdefault(clause.text, record)
    return worst


def scenario_digest(spec_digest: str, theta_repaired: Sequence[float], seed: int) -> str:
    """sha256 of the spec digest, the repaired theta and the seed: one scenario's identity."""
    payload = json.dumps([spec_digest, [float(v) for v in theta_repaired], int(seed)], separators=(",", ":"))
    return hashlib.sha256(payload.encode()).hexdigest()


def clauses_text(clauses: Sequence[Clause]) -> str:
    """``objective >= 15 (objective=17.2); approach >= 0.3 (approach=0.41)``: one line for humans."""
    return "; ".join(map(str, clauses))


def _number(value: float) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None


def _float(value: float | None) -> float:
    return math.nan if value is None else float(value)


def _or(value: float, default: float) -> float:
    return value if math.isfinite(value) else default


def _short(value: float) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)


__all__ = [
    "MAX_SEED",
    "Clause",
    "Evaluation",
    "EvaluationRecord",
    "Status",
    "clauses_text",
    "rank_failures",
    "scenario_digest",
    "worst_of_each_clause",
]
