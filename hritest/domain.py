"""A compiled spec: theta's layout and bounds, the plugins, and the compiled expressions.

``compile_spec`` is the one step between the declarative spec and everything that runs:
it resolves plugins, checks their parameters, and fixes the order of theta's components.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pydantic

from hritest import plugins
from hritest.constraints import ScenarioRepair
from hritest.scenario import ScenarioSpace, Slot
from hritest.errors import PluginError, SpecError
from hritest.spec import Spec, source_of
from hritest.spec import expr
from hritest.repair import InfeasibleConstraints
from hritest.spec.references import check_references


@dataclass(frozen=True, kw_only=True)
class Measure:
    name: str
    expression: expr.Expression
    range: tuple[float, float]
    cells: int


@dataclass(frozen=True, kw_only=True)
class Domain:
    """Everything a search needs from a spec, resolved and checked."""

    spec: Spec
    space: ScenarioSpace
    task_cls: type
    robot_cls: type
    human_cls: type
    objective: expr.Expression
    measures: tuple[Measure, ...]
    failure: expr.Expression
    repair: ScenarioRepair = field(repr=False)

    def evaluate(self, theta: np.ndarray, *, seed: int = 0) -> Any:
        """Repair -> simulate -> metrics for one theta: an :class:`hritest.evaluate.Evaluation`."""
        from hritest.evaluate import evaluate

        return evaluate(self, theta, seed=seed)

    @property
    def archive_dims(self) -> tuple[int, ...]:
        return tuple(m.cells for m in self.measures)

    @property
    def archive_ranges(self) -> tuple[tuple[float, float], ...]:
        return tuple(m.range for m in self.measures)


def compile_spec(spec: Spec, *, base: Path | None = None) -> Domain:
    """Resolves plugins and builds the :class:`Domain`.

    Args:
        base: the folder that ``file.py:Class`` plugin paths are relative to (the spec's folder).

    Raises:
        SpecError: a plugin that cannot be loaded, parameters it does not accept, or an
            expression name that neither the task's metrics nor the parameters define.
    """
    source = source_of(spec)
    base = base if base is not None else (Path(source.file).parent if source.file != "<spec>" else None)
    classes: dict[str, type] = {}
    issues = []
    for kind, path, ref in (("task", ("task", "name"), spec.task.name),
                            ("robot", ("robot", "policy"), spec.robot.policy),
                            ("human", ("human", "policy"), spec.human.policy)):
        try:
            classes[kind] = plugins.resolve(ref, kind=kind, base=base)
        except PluginError as exc:
            issues.append(source.issue(path, str(exc)))
    if issues:
        raise SpecError(issues, file=source.file)

    nominal = {
        "task": _plugin_params(classes["task"], spec.task.params, ("task", "params"), spec, source),
        "robot": _plugin_params(classes["robot"], spec.robot.params, ("robot", "params"), spec, source),
        "human": _plugin_params(classes["human"], spec.human.params, ("human", "params"), spec, source),
    }
    found = check_references(spec, metrics=getattr(classes["task"], "metrics", ()))
    if found:
        raise SpecError([source.issue(path, message) for path, message in found], file=source.file)

    space = ScenarioSpace(
        slots=_slots(spec),
        nominal_objects={o.name: np.array(o.position, dtype=float) for o in spec.objects},
        nominal_params=nominal,
    )
    repair = ScenarioRepair(spec=spec, space=space)
    try:
        repair.check_feasible()
    except InfeasibleConstraints as exc:
        raise source.error(("constraints",), f"no scenario satisfies these constraints: {exc}") from None
    return Domain(
        spec=spec,
        space=space,
        repair=repair,
        task_cls=classes["task"],
        robot_cls=classes["robot"],
        human_cls=classes["human"],
        objective=expr.parse(spec.objective.expr),
        measures=tuple(
            Measure(name=m.name, expression=expr.parse(m.expr), range=m.range, cells=m.cells)
            for m in spec.measures
        ),
        failure=expr.parse(spec.failure, condition=True),
    )


def _slots(spec: Spec) -> tuple[Slot, ...]:
    slots, start = [], 0
    for p in spec.parameters:
        slots.append(Slot(name=p.name, bind=p.bind, start=start, size=p.size, lower=p.bounds[0], upper=p.bounds[1]))
        start += p.size
    return tuple(slots)


def _plugin_params(cls: type, given: Mapping[str, Any], path: tuple, spec: Spec, source) -> dict[str, Any]:
    """Validates a plugin's ``params`` (and theta-bound names) against its ``Params`` model.

    A plugin without a ``Params`` model takes its params as given. Theta-bound names must be
    fields of the model, so a typo in ``bind: human.rationalty`` is caught here.
    """
    model = getattr(cls, "Params", None)
    agent = path[0]
    bound = [(i, p) for i, p in enumerate(spec.parameters) if p.bind.split(".")[0] == agent]
    if model is None:
        return dict(given)
    issues = [
        source.issue(("parameters", i, "bind"),
                     f"{cls.__name__} has no parameter {p.bind.split('.')[1]!r}; its parameters are "
                     f"{', '.join(model.model_fields) or 'none'}")
        for i, p in bound if p.bind.split(".")[1] not in model.model_fields
    ]
    try:
        params = model.model_validate(dict(given)).model_dump()
    except pydantic.ValidationError as exc:
        for error in exc.errors(include_url=False):
            issues.append(source.issue(path + tuple(error["loc"]), error["msg"]))
        params = {}
    if issues:
        raise SpecError(issues, file=source.file)
    return params

