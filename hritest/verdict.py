"""A corpus entry's verdict: what its replays say about it, decided in one place.

=========  ==================================  ==============================================
entry      its replays (one per seed)          verdict
=========  ==================================  ==============================================
fixed      every seed passes                   passing
fixed      any seed fails                      regression
open       every seed fails                    still failing
open       every seed passes                   now passing
open       some seeds fail, some pass          flaky (with its failure rate)
either     cannot be replayed or evaluated     error (spec gone or broken, a plugin error, a
                                               timeout, a dying worker, a tampered entry)
=========  ==================================  ==============================================

An entry is judged whatever changed since it was recorded; the outcome-relevant changes (see
:mod:`hritest.outcome_digest`) are carried beside the verdict, never instead of it. The pytest
plugin only maps verdicts to pytest outcomes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from hritest.corpus import Entry
from hritest.records import Clause, Evaluation, Status, clauses_text

THETA_TOLERANCE = 1e-9  # a stored repaired theta and the one its raw theta repairs to now
# Changing these parts may legitimately move the repaired theta; otherwise it must not move.
REPAIR_PARTS = ("scenario space", "scene", "constraints", "repair")


class Verdict(StrEnum):
    PASSING = "passing"
    REGRESSION = "regression"
    STILL_FAILING = "still failing"
    NOW_PASSING = "now passing"
    FLAKY = "flaky"
    ERROR = "error"


@dataclass(frozen=True, kw_only=True)
class SeedReplay:
    """One replay of an entry's scenario, with one seed."""

    seed: int
    status: Status
    failure: bool
    objective: float | None
    measures: Mapping[str, float | None]
    theta_repaired: tuple[float, ...]
    clauses: tuple[Clause, ...] = ()
    message: str = ""

    @property
    def fired(self) -> tuple[Clause, ...]:
        return tuple(c for c in self.clauses if c.holds)

    @classmethod
    def of(cls, evaluation: Evaluation, measure_names: Sequence[str]) -> SeedReplay:
        """The replay an evaluation is (non-finite numbers become None)."""
        return cls(
            seed=int(evaluation.seed),
            status=evaluation.status,
            failure=bool(evaluation.failure),
            objective=_finite(evaluation.objective),
            measures={name: _finite(v) for name, v in zip(measure_names, evaluation.measures)},
            theta_repaired=tuple(float(v) for v in evaluation.theta_repaired),
            clauses=evaluation.clauses,
            message=evaluation.message,
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "seed": self.seed,
            "status": self.status.value,
            "failure": self.failure,
            "objective": self.objective,
            "measures": dict(self.measures),
            "theta_repaired": list(self.theta_repaired),
            "clauses": [c.to_json() for c in self.clauses],
            "message": self.message,
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> SeedReplay:
        return cls(
            seed=int(data["seed"]),
            status=Status.parse(data["status"]),
            failure=bool(data["failure"]),
            objective=data["objective"],
            measures=dict(data["measures"]),
            theta_repaired=tuple(data["theta_repaired"]),
            clauses=tuple(Clause.from_json(c) for c in data["clauses"]),
            message=str(data.get("message", "")),
        )


@dataclass(frozen=True, kw_only=True)
class Judgement:
    """An entry's verdict, the one-line reason, the changes since it was recorded, and its replays."""

    verdict: Verdict
    reason: str
    changes: tuple[str, ...] = ()
    replays: tuple[SeedReplay, ...] = ()
    detail: str = ""  # recorded against now, for a report
    failure_rate: float | None = None

    @property
    def changed(self) -> str:
        """``(spec or plugins changed since this was recorded: task plugin source)``, or ``""``."""
        return f"(spec or plugins changed since this was recorded: {', '.join(self.changes)})" if self.changes else ""


def error(reason: str, *, changes: Sequence[str] = ()) -> Judgement:
    return Judgement(verdict=Verdict.ERROR, reason=reason, changes=tuple(changes))


def changes_since(entry: Entry, *, parts_now: Mapping[str, str], spec_digest_now: str) -> list[str]:
    """What changed since ``entry`` was recorded: the outcome digest's parts that differ, or, for an
    entry recorded before outcome digests, whether the spec file's bytes changed."""
    if entry.outcome_parts:
        recorded = dict(entry.outcome_parts)
        return [name for name in {**recorded, **parts_now} if recorded.get(name) != parts_now.get(name)]
    if entry.spec_digest != spec_digest_now:
        return ["the spec file (recorded before outcome digests: promote it again to track what changed)"]
    return []


def judge(entry: Entry, replays: Sequence[SeedReplay], *, changes: Sequence[str]) -> Judgement:
    """The verdict of ``entry`` from its ``replays`` (the recorded seed first)."""
    changes = tuple(changes)
    first = replays[0]
    broken = next((r for r in replays if r.status is not Status.OK), None)
    if broken is not None:
        return error(
            f"no longer evaluates: status {broken.status} (seed {broken.seed})\n{broken.message}".rstrip(),
            changes=changes,
        )
    if not set(REPAIR_PARTS) & set(changes):
        moved = [
            f"{label}: {now:.6g}, stored {then:.6g}"
            for label, then, now in zip(entry.theta_repaired, entry.theta_repaired.values(), first.theta_repaired)
            if abs(then - now) > THETA_TOLERANCE
        ]
        if moved:
            return error(
                f"{entry.path}: field 'theta' does not repair to the stored field 'theta_repaired' "
                f"({'; '.join(moved)}), and neither the scenario space nor the constraints or their repair "
                "changed: the entry was edited. Restore it from version control, or promote the failure again",
                changes=changes,
            )
    failing = [r for r in replays if r.failure]
    rate = len(failing) / len(replays)
    seeds = f" with {len(failing)} of {len(replays)} seeds" if len(replays) > 1 else ""
    why = clauses_text(failing[0].fired) if failing else ""
    detail = then_now(entry, failing[0] if failing else first)
    if entry.status == "fixed":
        if failing:
            return Judgement(
                verdict=Verdict.REGRESSION,
                reason=f"was marked fixed but fails again{seeds}: {why}",
                changes=changes,
                replays=tuple(replays),
                detail=detail,
                failure_rate=rate,
            )
        return Judgement(verdict=Verdict.PASSING, reason="passes", changes=changes, replays=tuple(replays))
    if not failing:
        return Judgement(
            verdict=Verdict.NOW_PASSING,
            reason=f"no longer fails: '{entry.failure_condition or 'the failure condition'}' does not hold{seeds}",
            changes=changes,
            replays=tuple(replays),
            detail=detail,
            failure_rate=0.0,
        )
    verdict = Verdict.STILL_FAILING if len(failing) == len(replays) else Verdict.FLAKY
    passing = [r.seed for r in replays if not r.failure]
    reason = f"still fails{seeds}: {why}" + (f"; passes with seed {', '.join(map(str, passing))}" if passing else "")
    return Judgement(
        verdict=verdict,
        reason=reason,
        changes=changes,
        replays=tuple(replays),
        detail=detail,
        failure_rate=rate,
    )


def then_now(entry: Entry, replay: SeedReplay) -> str:
    """A table of the recorded objective, measures and clauses against the replay's (and its seed)."""

    def show(value: float | None) -> str:
        return "-" if value is None else f"{value:.6g}"

    rows = [("objective", show(entry.objective), show(replay.objective))]
    rows += [(name, show(value), show(replay.measures.get(name))) for name, value in entry.measures.items()]
    width = max(len(r[0]) for r in rows)
    lines = [f"  {'':{width}}  {'recorded':>12}  {'now':>12}"]
    lines += [f"  {name:{width}}  {then:>12}  {now:>12}" for name, then, now in rows]
    lines.append(f"  recorded: fails {'; '.join(entry.why) or '(clauses not recorded)'}")
    lines.append(
        f"  now:      {'fails ' + clauses_text(replay.fired) if replay.failure else 'passes'}"
        + ("" if replay.seed == entry.seed else f" (seed {replay.seed}; recorded with seed {entry.seed})")
    )
    return "\n".join(lines)


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


__all__ = ["Judgement", "SeedReplay", "Verdict", "changes_since", "error", "judge", "then_now"]
