"""One scenario, start to end: repair -> simulate -> metrics, as a picklable :class:`Evaluation`.

Nothing raised by a plugin escapes: a crash, a NaN or a failed repair becomes an Evaluation
with a status and a message naming the plugin, so a search never stops for one bad scenario.
"""

from __future__ import annotations

import math
import time
import traceback
from dataclasses import replace
from typing import Any

import numpy as np

from hritest import contract
from hritest.domain import Domain, plugin_params
from hritest.protocols import Rollout
from hritest.records import Clause, Evaluation, Status
from hritest.scenario import Scenario


def evaluate(domain: Domain, theta: np.ndarray, *, seed: int = 0) -> Evaluation:
    """Repairs, simulates and scores ``theta``."""
    return evaluate_with_rollout(domain, theta, seed=seed)[0]


def evaluate_with_rollout(domain: Domain, theta: np.ndarray, *, seed: int = 0) -> tuple[Evaluation, Rollout | None]:
    """:func:`evaluate`, also returning the rollout (None when the scenario did not simulate).

    For recording and replay; searches call :func:`evaluate`, since rollouts are large.
    """
    start = time.perf_counter()
    theta = np.asarray(theta, dtype=float)
    repaired = domain.repair(theta)
    base = {
        "theta": theta.copy(),
        "theta_repaired": repaired.theta,
        "repair_cost": repaired.cost,
        "regions": repaired.regions,
        "seed": seed,
    }
    rollout = None
    if not repaired.ok:
        evaluation = Evaluation(**base, status=Status(repaired.status), message=repaired.message)
    else:
        scenario = domain.space.bind(repaired.theta)
        try:
            rollout = simulate(domain, scenario, seed=seed)
        # A plugin's sys.exit() or KeyboardInterrupt ends its scenario, not the caller: a real
        # Ctrl-C reaches hritest's commands as hritest.interrupt.Interrupted, which passes through.
        except (Exception, SystemExit, KeyboardInterrupt) as exc:
            evaluation = Evaluation(**base, status=Status.PLUGIN_ERROR, message=_blame(domain, exc))
        else:
            evaluation = _score(domain, scenario, rollout, base)
    return replace(evaluation, seconds=time.perf_counter() - start), rollout


def simulate(domain: Domain, scenario: Scenario, *, seed: int) -> Rollout:
    """Builds the plugins for ``scenario`` and runs one episode; exceptions propagate."""
    task_rng, robot_rng, human_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3))
    task = domain.task_cls(context=domain.context(scenario))
    robot = domain.robot_cls(params=plugin_params(domain.robot_cls, scenario.robot), scenario=scenario, rng=robot_rng)
    human = domain.human_cls(params=plugin_params(domain.human_cls, scenario.human), scenario=scenario, rng=human_rng)
    return task.run(robot=robot, human=human, rng=task_rng)


def _score(domain: Domain, scenario: Scenario, rollout: Rollout, base: dict) -> Evaluation:
    broken = contract.rollout_problems(domain.task_cls, rollout)
    if broken:
        return Evaluation(
            **base, status=Status.PLUGIN_ERROR, message="the task plugin broke the contract: " + "; ".join(broken)
        )
    missing = contract.missing_metrics(domain.task_cls, rollout)
    if missing:
        return Evaluation(**base, status=Status.METRIC_ERROR, message="; ".join(missing))
    env: dict[str, Any] = {**rollout.metrics, **scenario.values}
    try:
        objective = float(domain.objective.evaluate(env))
        measures = np.array([float(m.expression.evaluate(env)) for m in domain.measures])
    except (KeyError, ZeroDivisionError, ValueError, TypeError, IndexError) as exc:
        return Evaluation(
            **base,
            status=Status.METRIC_ERROR,
            message=f"{type(exc).__name__}: {exc} (metrics: {sorted(rollout.metrics)})",
        )
    occupancy = np.stack([rollout.grids[name] for name in domain.grids]) if domain.grids else None
    if not (math.isfinite(objective) and np.all(np.isfinite(measures))):
        return Evaluation(
            **base,
            status=Status.NAN,
            objective=objective,
            measures=measures,
            metrics=dict(rollout.metrics),
            message=f"objective {objective} or measures {measures.tolist()} not finite",
        )
    env.update({"objective": objective, **{m.name: v for m, v in zip(domain.measures, measures)}})
    try:
        clauses = tuple(
            Clause(text=c.text, holds=bool(c.evaluate(env)), values={n: _scalar(env[n]) for n in sorted(c.names)})
            for c in domain.failure.clauses()
        )
        failure = bool(domain.failure.evaluate(env))
    except (KeyError, ZeroDivisionError, ValueError, TypeError, IndexError) as exc:
        return Evaluation(
            **base, status=Status.METRIC_ERROR, message=f"the failure condition: {type(exc).__name__}: {exc}"
        )
    return Evaluation(
        **base,
        objective=objective,
        search_objective=objective - domain.spec.objective.repair_weight * base["repair_cost"],
        measures=measures,
        metrics={k: float(v) for k, v in rollout.metrics.items()},
        occupancy=occupancy,
        failure=failure,
        clauses=clauses,
    )


def _scalar(value: object) -> float | list[float]:
    """A clause's value as JSON can hold it: a number, or a parameter group as a list."""
    array = np.asarray(value, dtype=float)
    return float(array) if array.ndim == 0 else array.tolist()


def _blame(domain: Domain, exc: BaseException) -> str:
    """A message naming the plugin whose method was running deepest, with the traceback."""
    plugins = {
        (cls.__module__, cls.__qualname__): (kind, cls)
        for kind, cls in (("task", domain.task_cls), ("robot", domain.robot_cls), ("human", domain.human_cls))
    }
    culprit = None
    for frame, _ in traceback.walk_tb(exc.__traceback__):
        owner = frame.f_code.co_qualname.rsplit(".", 1)[0]
        culprit = plugins.get((frame.f_globals.get("__name__"), owner), culprit)
    where = f"{culprit[0]} plugin {culprit[1].__qualname__}" if culprit else "the simulation"
    trace = "".join(traceback.format_exception(exc)).rstrip()
    return f"{where} raised {type(exc).__name__}: {exc}\n{trace}"
