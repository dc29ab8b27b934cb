"""A failure beside the nearest passing scenario found (:mod:`hritest.counterfactual`), for the
report; searched once per scenario and kept in ``<run>/counterfactuals/<id>.json``."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hritest.records import EvaluationRecord
from hritest.report.run import RunData
from hritest.rundir import atomic_write

BUDGET = 40  # simulations the report spends looking for a failure's counterfactual


@dataclass(frozen=True)
class Contrast:
    """``failure`` and the passing scenario nearest to it that the search found (``passing`` holds
    its ``theta``, ``objective``, ``measures`` and ``metrics``), or why none was found."""

    failure: EvaluationRecord
    passing: dict[str, Any] | None
    recording: Path | None = None  # both episodes side by side, on one timeline
    changed: tuple[str, ...] = ()
    distance: float = float("nan")
    evaluations: int = 0
    reason: str = ""


def contrast(data: RunData, failure: EvaluationRecord, *, search: bool = True, budget: int = BUDGET) -> Contrast:
    """The counterfactual of ``failure``: read back if this scenario's was searched before, else
    searched now (unless not ``search``)."""
    from hritest.counterfactual import CounterfactualError, counterfactual
    from hritest.records import scenario_digest

    path = data.path / "counterfactuals" / f"{failure.index}.json"
    digest = scenario_digest(data.meta["spec_digest"], failure.theta_repaired, failure.seed)
    try:
        stored = json.loads(path.read_text())
    except (OSError, ValueError):
        stored = {}
    if stored.get("digest") != digest and not search:
        return Contrast(failure=failure, passing=None, reason="not searched for this report (--recordings 0)")
    if stored.get("digest") != digest:
        domain = data.domain()
        try:
            found = counterfactual(domain, failure.theta, seed=failure.seed, budget=budget)
        except CounterfactualError as exc:
            stored = {"digest": digest, "reason": str(exc)}
        else:
            passing = found.passing
            _record(domain, data, failure, found, path.with_suffix(".rrd"))
            stored = {
                "digest": digest,
                "passing": {
                    "theta": found.theta.tolist(),
                    "theta_repaired": passing.theta_repaired.tolist(),
                    "objective": passing.objective,
                    "measures": passing.measures.tolist(),
                    "metrics": dict(passing.metrics),
                },
                "changed": list(found.changed),
                "distance": found.distance,
                "evaluations": found.evaluations,
            }
        path.parent.mkdir(exist_ok=True)
        atomic_write(path, json.dumps(stored, indent=1))
    recording = path.with_suffix(".rrd")
    return Contrast(
        failure=failure,
        passing=stored.get("passing"),
        recording=recording if stored.get("passing") and recording.is_file() else None,
        changed=tuple(stored.get("changed", ())),
        distance=float(stored.get("distance", float("nan"))),
        evaluations=int(stored.get("evaluations", 0)),
        reason=stored.get("reason", ""),
    )


def _record(domain: Any, data: RunData, failure: EvaluationRecord, found: Any, path: Path) -> None:
    """The failure and its counterfactual simulated again with their rollouts, into one recording."""
    from hritest.evaluate import evaluate_with_rollout
    from hritest.recording import Episode, write_episodes
    from hritest.records import scenario_digest

    episodes = []
    for name, theta in (("failure", failure.theta), ("passing", found.theta)):
        evaluation, rollout = evaluate_with_rollout(domain, theta, seed=failure.seed)
        episodes.append(Episode(name, evaluation, rollout, f"{data.spec.name}: failure {failure.index}, {name}"))
    digest = scenario_digest(data.meta["spec_digest"], found.theta, failure.seed)
    write_episodes(path, domain=domain, episodes=episodes, recording_id=f"counterfactual-{digest}")
