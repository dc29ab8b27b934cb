"""``hritest check``: a spec and its plugins tried on a few scenarios before a long search.

Gymnasium's ``check_env`` is the model: compile, run the nominal scenario and a few random ones,
and turn every broken promise of the plugin contract (:mod:`hritest.contract`) into one finding
that says what to change. It also says what one scenario costs, so a budget can be chosen.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from hritest import contract
from hritest.domain import Domain, load_domain
from hritest.evaluate import evaluate_with_rollout
from hritest.protocols import Rollout
from hritest.records import Evaluation


@dataclass(frozen=True, kw_only=True)
class Finding:
    """One broken promise: which check, in which scenario, and what to change."""

    check: str
    scenario: str
    message: str

    def __str__(self) -> str:
        return f"[{self.check}] {self.scenario}: {self.message}"


@dataclass(frozen=True, kw_only=True)
class CheckReport:
    """What ``hritest check`` found: findings (empty = the spec is ready), notes, and costs."""

    spec: str
    findings: tuple[Finding, ...] = ()
    passed: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    seconds: tuple[float, ...] = ()
    budget: int = 0

    @property
    def ok(self) -> bool:
        return not self.findings

    @property
    def seconds_per_scenario(self) -> float:
        return statistics.median(self.seconds) if self.seconds else float("nan")


@dataclass
class _Checker:
    domain: Domain
    findings: list[Finding] = field(default_factory=list)
    passed: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)

    def scenario(self, label: str, theta: np.ndarray, seed: int) -> tuple[Evaluation, Rollout | None]:
        evaluation, rollout = evaluate_with_rollout(self.domain, theta, seed=seed)
        self.seconds.append(evaluation.seconds)
        if not evaluation.ok:
            self.find(evaluation.status, label, _fix(evaluation))
        elif rollout is not None:
            for problem in contract.nonfinite_metrics(rollout):
                self.find(
                    "metrics", label, f"{problem}; a search survives it, but an expression that reads it will fail"
                )
        return evaluation, rollout

    def find(self, check: str, label: str, message: str) -> None:
        """Adds a finding; one that repeats an earlier one only adds its scenario to it."""
        for i, seen in enumerate(self.findings):
            if (seen.check, seen.message) == (check, message):
                self.findings[i] = replace(seen, scenario=f"{seen.scenario}, {label}")
                return
        self.findings.append(Finding(check=check, scenario=label, message=message))


def check_spec(path: Path, *, scenarios: int = 3, seed: int = 0) -> CheckReport:
    """Compiles ``path`` and tries its nominal scenario and ``scenarios`` random ones.

    Raises:
        SpecError: the spec does not load or compile (the CLI prints it as the only finding).
    """
    domain = load_domain(path)
    checker = _Checker(domain=domain)
    checker.passed.append(
        f"spec compiles: theta has {domain.space.dim} components, task {domain.task_cls.__qualname__}, "
        f"robot {domain.robot_cls.__qualname__}, human {domain.human_cls.__qualname__}"
    )
    nominal, rollout = checker.scenario("nominal scenario", domain.nominal, seed)
    if nominal.ok:
        checker.passed.append(
            f"nominal scenario: objective {nominal.objective:.4g}, "
            f"failure {nominal.failure}, metrics {_short(nominal.metrics)}"
        )
        again, _ = checker.scenario("nominal scenario, again", domain.nominal, seed)
        if _outcome(again) != _outcome(nominal):
            checker.find(
                "determinism",
                "nominal scenario",
                (
                    f"the same theta and seed gave {_outcome(nominal)} and then {_outcome(again)}; draw every random "
                    "number from the rng each plugin is given (never np.random or random directly) and keep no "
                    "state between episodes"
                ),
            )
        elif again.ok:
            checker.passed.append("same seed, same outcome")
    rng = np.random.default_rng(seed)
    outcomes = []
    for i in range(scenarios):
        theta = rng.uniform(domain.space.lower, domain.space.upper)
        evaluation, _ = checker.scenario(f"random scenario {i + 1}", theta, seed + 1 + i)
        outcomes.append(evaluation)
    ok = [e for e in outcomes if e.ok]
    if ok:
        checker.passed.append(
            f"{len(ok)} of {len(outcomes)} random scenarios ok; objectives "
            + ", ".join(f"{e.objective:.4g}" for e in ok)
        )
    lo, hi = domain.spec.objective.range
    outside = sorted({e.objective for e in [nominal, *ok] if e.ok and not lo <= e.objective <= hi})
    if outside:
        checker.notes.append(
            f"objective {', '.join(f'{v:.4g}' for v in outside)} outside objective.range [{lo:g}, {hi:g}]: the "
            "QD-score counts each elite's objective minus the range's low end, so widen the range to cover it"
        )
    if rollout is not None:
        checker.notes += _recording_notes(rollout, domain)
    return CheckReport(
        spec=str(path),
        findings=tuple(checker.findings),
        passed=tuple(checker.passed),
        notes=tuple(checker.notes),
        seconds=tuple(checker.seconds),
        budget=domain.spec.search.budget,
    )


def _fix(evaluation: Evaluation) -> str:
    """The evaluation's message with what to do about its status."""
    first = evaluation.message.split("\nTraceback")[0].strip()
    advice = {
        "plugin_error": "fix the plugin named above (the traceback is in `hritest simulate SPEC --theta ...`)",
        "metric_error": "report every metric the task declares, and use only those names in expressions",
        "nan": "the objective or a measure is not finite: check the expressions and the metrics they read",
    }.get(evaluation.status, "check the constraints: the repair could not place this scenario")
    return f"{first} -> {advice}"


def _outcome(evaluation: Evaluation) -> tuple:
    return (
        evaluation.status,
        evaluation.objective,
        tuple(np.asarray(evaluation.measures).tolist()),
        tuple(sorted(evaluation.metrics.items())),
    )


def _short(metrics: dict[str, float]) -> str:
    return ", ".join(f"{k}={v:.4g}" for k, v in list(metrics.items())[:4]) + (", ..." if len(metrics) > 4 else "")


def _recording_notes(rollout: Rollout, domain: Domain) -> list[str]:
    notes = []
    if rollout.scene is None and not rollout.trajectories:
        notes.append(
            "the rollout has no scene and no trajectories: recordings will show only the scenario "
            "document (add Rollout(trajectories=...) or, with MuJoCo, Rollout(scene=world.tracer()...))"
        )
    if not domain.grids:
        notes.append("the task declares no grids: SAS/DSAS's surrogate predicts from theta alone")
    return notes


__all__ = ["CheckReport", "Finding", "check_spec"]
