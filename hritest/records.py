"""The records that cross a stage boundary: an evaluation's status, the failure clauses that held,
and the evaluation itself, with the JSON form the run directory, the corpus and ``--json`` share.

Every status an evaluation can end with is a :class:`Status`; nothing compares status strings.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np


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


def clauses_text(clauses: Sequence[Clause]) -> str:
    """``objective >= 15 (objective=17.2); approach >= 0.3 (approach=0.41)``: one line for humans."""
    return "; ".join(map(str, clauses))


def _short(value: float) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)


__all__ = ["Clause", "Evaluation", "Status", "clauses_text"]
