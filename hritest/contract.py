"""Whether plugins follow :mod:`hritest.protocols`: their classes before a run, their rollouts after.

Each check returns plain sentences that say what to change, so :func:`hritest.domain.compile_spec`,
:func:`hritest.evaluate.evaluate` and ``hritest check`` can each report them their own way.
Plugins written against hritest 0.1's contract (``Task(params, scenario, spec)``, ``agents``,
``Rollout(robot_ee=..., joints=...)``) are recognised and get a migration message.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Mapping

import numpy as np

from hritest.protocols import Rollout

GRID_SHAPE = (32, 32)  # what the surrogate's networks take (the paper's)
MIGRATION = "docs/writing-a-domain.md, 'Migrating from hritest 0.1'"


def class_problems(cls: type, *, kind: str) -> list[str]:
    """What is wrong with a plugin class of ``kind`` (task, robot or human), before any episode."""
    name = plugin_name(cls)
    if kind != "task":
        problems = _keywords(cls, ("params", "scenario", "rng"), name)
        if not callable(getattr(cls, "act", None)):
            problems.append(f"{name} has no act(observation) method; a {kind} policy returns its action from it")
        return problems
    problems = _keywords(cls, ("context",), name)
    if "spec" in _parameters(cls):
        problems = [
            f"{name}: __init__ takes the spec (hritest 0.1); it now takes one keyword, context (a "
            f"hritest.protocols.TaskContext with dt, time_limit, params, scenario, world): see {MIGRATION}"
        ]
    if not callable(getattr(cls, "run", None)):
        problems.append(f"{name} has no run(*, robot, human, rng) method returning a hritest.protocols.Rollout")
    metrics = getattr(cls, "metrics", None)
    if not (isinstance(metrics, tuple) and all(isinstance(m, str) for m in metrics)):
        problems.append(
            f"{name}: the metrics class attribute must be a tuple of the metric names it reports, e.g. "
            f"metrics = ('completion_time',); it is {metrics!r}"
        )
    if hasattr(cls, "agents") and not hasattr(cls, "grids"):
        problems.append(
            f"{name} declares agents (hritest 0.1); declare its occupancy grids instead, "
            f"grids = {{{', '.join(f'{a!r}: (32, 32)' for a in cls.agents)}}}, and return them as "
            f"Rollout(grids=...): see {MIGRATION}"
        )
    else:
        problems += _grid_declaration(cls, name)
    return problems


def rollout_problems(cls: type, rollout: object) -> list[str]:
    """What is wrong with a task's rollout: its type, its time axis, its grids, its named arrays.

    Metrics are checked apart (:func:`missing_metrics`): a missing metric is a metric error.
    """
    problems = _rollout_problems(cls, rollout)
    if not problems:  # the common case, and what every evaluation pays: name the file only when needed
        return []
    name = plugin_name(cls)
    return [f"{name}: {problem}" for problem in problems]


def _rollout_problems(cls: type, rollout: object) -> list[str]:
    """:func:`rollout_problems`' sentences, without the plugin's name."""
    if not isinstance(rollout, Rollout):
        return [f"run returned {type(rollout).__name__}, not a hritest.protocols.Rollout"]
    problems = []
    time = np.asarray(rollout.time, dtype=float)
    if time.ndim != 1 or len(time) == 0:
        return [f"Rollout.time must be a 1-D array with one entry per recorded tick, got shape {time.shape}"]
    if not (np.all(np.isfinite(time)) and np.all(np.diff(time) >= 0)):
        problems.append("Rollout.time must be finite and non-decreasing")
    ticks = len(time)
    declared = dict(getattr(cls, "grids", {}))
    if set(rollout.grids) != set(declared):
        problems.append(
            f"it declares grids {sorted(declared)} but returned {sorted(rollout.grids)}; return "
            "exactly the declared ones (or change the grids class attribute)"
        )
    for grid_name, grid in rollout.grids.items():
        shape = np.shape(grid)
        if grid_name in declared and shape != tuple(declared[grid_name]):
            problems.append(f"grid {grid_name!r} has shape {shape}, declared {tuple(declared[grid_name])}")
    for traj_name, points in rollout.trajectories.items():
        shape = np.shape(points)
        if len(shape) != 2 or shape[1] != 3 or shape[0] > ticks:
            problems.append(
                f"trajectory {traj_name!r} has shape {shape}; it needs (n, 3) world positions "
                f"with n <= {ticks} (one per entry of time)"
            )
    for series_name, values in rollout.series.items():
        shape = np.shape(values)
        if len(shape) != 1 or shape[0] > ticks:
            problems.append(f"series {series_name!r} has shape {shape}; it needs (n,) with n <= {ticks}")
    for agent, states in rollout.states.items():
        if len(states) > ticks:
            problems.append(f"states of {agent!r} has {len(states)} entries for {ticks} ticks")
    return problems


def missing_metrics(cls: type, rollout: Rollout) -> list[str]:
    """Declared metrics the rollout does not report."""
    return [
        f"{plugin_name(cls)} declares metric {metric!r} but its Rollout.metrics lacks it; report it, or "
        "remove it from the metrics class attribute"
        for metric in getattr(cls, "metrics", ())
        if metric not in rollout.metrics
    ]


def nonfinite_metrics(rollout: Rollout) -> list[str]:
    """Reported metrics that are not finite numbers (a search survives them; a check flags them)."""
    problems = []
    for metric, value in rollout.metrics.items():
        try:
            finite = math.isfinite(float(value))
        except (TypeError, ValueError):
            finite = False
        if not finite:
            problems.append(f"metric {metric!r} = {value!r} is not a finite number")
    return problems


def plugin_name(cls: type) -> str:
    """``Class (file.py:line)``: where a user finds the plugin a message is about."""
    try:
        file, line = inspect.getsourcefile(cls), inspect.getsourcelines(cls)[1]
    except (OSError, TypeError):  # defined in a REPL, or a builtin: the name alone
        return cls.__qualname__
    return f"{cls.__qualname__} ({file}:{line})"


def _grid_declaration(cls: type, name: str) -> list[str]:
    grids = getattr(cls, "grids", {})
    if not isinstance(grids, Mapping):
        return [
            f"{name}: the grids class attribute must map each grid's name to its shape, "
            f"e.g. grids = {{'robot': (32, 32)}}; "
            f"it is {grids!r}"
        ]
    return [
        f"{name}: grids[{grid!r}] is {shape!r}; the surrogate takes {GRID_SHAPE} grids (bin with "
        "hritest.metrics.occupancy_grid)"
        for grid, shape in grids.items()
        if tuple(shape) != GRID_SHAPE
    ]


def _parameters(cls: type) -> dict[str, inspect.Parameter]:
    try:
        return dict(inspect.signature(cls).parameters)
    except (TypeError, ValueError):  # a builtin or C class: nothing to inspect
        return {}


def _keywords(cls: type, names: tuple[str, ...], qualname: str) -> list[str]:
    parameters = _parameters(cls)
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters.values()):
        return []
    missing = [n for n in names if n not in parameters]
    if not missing:
        return []
    wanted = ", ".join(names)
    return [
        f"{qualname}: __init__ must accept the keyword argument{'s' if len(names) > 1 else ''} {wanted} "
        f"(it lacks {', '.join(missing)})"
    ]
