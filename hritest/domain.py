"""A compiled spec: theta's layout and bounds, the plugins, and the compiled expressions.

``compile_spec`` is the one step between the declarative spec and everything that runs:
it resolves plugins, checks their parameters, and fixes the order of theta's components.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pydantic

from hritest import contract, plugin_loader
from hritest.constraints import ScenarioRepair
from hritest.errors import HritestError, PluginError, SpecError
from hritest.protocols import TaskContext
from hritest.repair import InfeasibleConstraints
from hritest.scenario import Scenario, ScenarioSpace, Slot
from hritest.sim.layout import START_CONFIG, ArmMount, BodyPose, Box, WorldLayout
from hritest.spec import Spec, expr, load_spec, source_of
from hritest.spec.references import ARM_TARGET, check_references
from hritest.spec.source import SourceMap, read_yaml

# Where each plugin is named in a spec, by kind.
PLUGIN_FIELDS = {"task": ("task", "name"), "robot": ("robot", "policy"), "human": ("human", "policy")}
REGION_COLOUR = (0.55, 0.75, 0.95, 0.6)
OBJECT_COLOUR = (0.9, 0.5, 0.1, 1.0)


@dataclass(frozen=True, kw_only=True)
class Measure:
    name: str
    expression: expr.Expression
    range: tuple[float, float]
    cells: int | None  # along this measure, for a grid archive


@dataclass(frozen=True, kw_only=True)
class Domain:
    """Everything a search needs from a spec, resolved and checked.

    ``world`` is the MuJoCo world of the spec's ``world``/``workspace`` sections at the nominal
    placement (``None`` without either); :meth:`context` places it for one scenario. ``nominal``
    is theta of the nominal scenario.
    """

    spec: Spec
    space: ScenarioSpace
    task_cls: type
    robot_cls: type
    human_cls: type
    objective: expr.Expression
    measures: tuple[Measure, ...]
    failure: expr.Expression
    repair: ScenarioRepair = field(repr=False)
    nominal: np.ndarray = field(repr=False)
    world: WorldLayout | None = None
    folder: Path | None = None

    def context(self, scenario: Scenario) -> TaskContext:
        """What the task gets for ``scenario``: never the spec."""
        return TaskContext(
            dt=self.spec.task.dt,
            time_limit=self.spec.task.time_limit,
            params=plugin_params(self.task_cls, scenario.task),
            scenario=scenario,
            world=None if self.world is None else place(self.world, scenario),
            folder=self.folder,
        )

    @property
    def grids(self) -> Mapping[str, tuple[int, int]]:
        """The occupancy grids the task declares, name -> shape, in its order."""
        return dict(getattr(self.task_cls, "grids", {}))

    @property
    def archive_dims(self) -> tuple[int, ...]:
        """A grid archive's cells per measure."""
        return tuple(m.cells for m in self.measures)

    @property
    def archive_cells(self) -> int:
        """How many cells the result archive has, grid or cvt."""
        return self.spec.archive.cells if self.spec.archive.type == "cvt" else math.prod(self.archive_dims)

    @property
    def archive_ranges(self) -> tuple[tuple[float, float], ...]:
        return tuple(m.range for m in self.measures)


def plugin_params(cls: type, values: Mapping[str, Any]) -> Any:
    """A plugin's params as it receives them: its ``Params`` model, or the dict if it has none."""
    model = getattr(cls, "Params", None)
    return model.model_validate(dict(values)) if model is not None else dict(values)


def place(layout: WorldLayout, scenario: Scenario) -> WorldLayout:
    """``layout`` with the objects, the arm and the world model's bodies where ``scenario`` puts them."""
    objects = tuple(replace(box, center=tuple(float(v) for v in scenario.objects[box.name])) for box in layout.objects)
    bodies, arm = dict(layout.bodies), layout.arm
    for name, values in scenario.bodies.items():
        if name == ARM_TARGET:
            base = list(arm.base)
            for axis, attribute in enumerate("xyz"):
                if attribute in values:
                    base[axis] = float(values[attribute])
            start = values.get("start", arm.start)
            arm = replace(
                arm,
                base=tuple(base),
                yaw=float(values.get("yaw", arm.yaw)),
                start=None if start is None else tuple(float(v) for v in np.ravel(start)),
            )
        else:
            pose = bodies.get(name, BodyPose())
            bodies[name] = replace(pose, **{k: float(v) for k, v in values.items()})
    return replace(layout, objects=objects, bodies=bodies, arm=arm)


def compile_spec(spec: Spec, *, base: Path | None = None) -> Domain:
    """Resolves plugins and builds the :class:`Domain`.

    Args:
        base: the folder that ``file.py:Class`` plugin paths and model files are relative to
            (default: the spec's folder).

    Raises:
        SpecError: a plugin that cannot be loaded or breaks the plugin contract, parameters it
            does not accept (bounds included), an expression name that neither the task's
            metrics nor the parameters define, or a world model that does not build.
    """
    source = source_of(spec)
    base = base if base is not None else (Path(source.file).parent if source.file != "<spec>" else None)
    refs = {"task": spec.task.name, "robot": spec.robot.policy, "human": spec.human.policy}
    classes, issues = _resolve_plugins(refs, base=base, source=source)
    if issues:
        raise SpecError(issues, file=source.file)

    nominal, issues = {}, []
    for kind, given in (("task", spec.task.params), ("robot", spec.robot.params), ("human", spec.human.params)):
        try:  # each plugin's params on their own: what all three reject is reported at once
            nominal[kind] = _plugin_params(classes[kind], given, (kind, "params"), spec, source)
        except SpecError as exc:
            issues += exc.issues
    if issues:
        raise SpecError(issues, file=source.file)
    found = check_references(spec, metrics=getattr(classes["task"], "metrics", ()))
    if found:
        raise SpecError([source.issue(path, message) for path, message in found], file=source.file)

    space = ScenarioSpace(
        slots=_slots(spec),
        nominal_objects={o.name: np.array(o.position, dtype=float) for o in spec.objects},
        nominal_params=nominal,
    )
    world = _world(spec, base)
    theta0 = _nominal_theta(spec, space, world)
    if world is not None:
        _check_world(spec, world, space.bind(theta0), source)
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
            Measure(name=m.name, expression=expr.parse(m.expr), range=m.range, cells=m.cells) for m in spec.measures
        ),
        failure=expr.parse(spec.failure, condition=True),
        nominal=theta0,
        world=world,
        folder=base,
    )


def load_domain(path: str | Path, *, base: Path | None = None) -> Domain:
    """Loads and compiles the spec at ``path``, with every independent problem in one error.

    The plugins a spec names do not depend on the rest of it, so they are resolved even when
    the spec has schema or name problems, and what is wrong with them is reported alongside.

    Raises:
        SpecError: as :func:`hritest.spec.load_spec` and :func:`compile_spec` do.
    """
    try:
        spec = load_spec(path)
    except SpecError as exc:
        raise SpecError(exc.issues + _plugin_issues(path, base), file=exc.file) from None
    return compile_spec(spec, base=base)


def _plugin_issues(path: str | Path, base: Path | None) -> list:
    """What is wrong with the plugins a spec file names, read from its data before any validation."""
    try:
        data, source = read_yaml(path)
    except SpecError:
        return []  # not a readable mapping: the first error says so
    refs = {}
    for kind, (section, key) in PLUGIN_FIELDS.items():
        ref = data[section].get(key) if isinstance(data.get(section), dict) else None
        if isinstance(ref, str):
            refs[kind] = ref
    return _resolve_plugins(refs, base=base if base is not None else Path(source.file).parent, source=source)[1]


def _resolve_plugins(refs: Mapping[str, str], *, base: Path | None, source: SourceMap) -> tuple[dict[str, type], list]:
    """The plugin classes ``refs`` name (kind -> reference), and the problems of those that fail."""
    classes: dict[str, type] = {}
    issues = []
    for kind, ref in refs.items():
        try:
            classes[kind] = plugin_loader.resolve(ref, kind=kind, base=base)
        except PluginError as exc:
            issues.append(source.issue(PLUGIN_FIELDS[kind], str(exc)))
        else:
            issues += [
                source.issue(PLUGIN_FIELDS[kind], f"{kind} plugin {ref!r}: {problem}")
                for problem in contract.class_problems(classes[kind], kind=kind)
            ]
    return classes, issues


def _slots(spec: Spec) -> tuple[Slot, ...]:
    slots, start = [], 0
    for p in spec.parameters:
        slots.append(Slot(name=p.name, bind=p.bind, start=start, size=p.size, lower=p.bounds[0], upper=p.bounds[1]))
        start += p.size
    return tuple(slots)


def _plugin_params(cls: type, given: Mapping[str, Any], path: tuple, spec: Spec, source: SourceMap) -> dict[str, Any]:
    """Validates a plugin's ``params`` (and theta-bound names and bounds) against its ``Params`` model.

    A plugin without a ``Params`` model takes its params as given. Theta-bound names must be
    fields of the model, so a typo in ``bind: human.rationalty`` is caught here, and both ends of
    a bound parameter's bounds must be values the model accepts, so that no scenario the search
    proposes can fail its validation.
    """
    model = getattr(cls, "Params", None)
    agent = path[0]
    bound = [(i, p) for i, p in enumerate(spec.parameters) if p.bind.split(".")[0] == agent]
    if model is None:
        return dict(given)
    issues = [
        source.issue(
            ("parameters", i, "bind"),
            f"{cls.__name__} has no parameter {p.bind.split('.')[1]!r}; its parameters are "
            f"{', '.join(model.model_fields) or 'none'}",
        )
        for i, p in bound
        if p.bind.split(".")[1] not in model.model_fields
    ]
    try:
        params = model.model_validate(dict(given)).model_dump()
    except pydantic.ValidationError as exc:
        for error in exc.errors(include_url=False):
            issues.append(source.issue(path + tuple(error["loc"]), error["msg"]))
        params = {}
    if not issues:
        for i, p in bound:
            attribute = p.bind.split(".")[1]
            for end in p.bounds:
                value = end if p.size == 1 else np.full(p.size, end)
                try:
                    model.model_validate({**params, attribute: value})
                except pydantic.ValidationError as exc:
                    reason = "; ".join(e["msg"] for e in exc.errors(include_url=False))
                    issues.append(
                        source.issue(
                            ("parameters", i, "bounds"),
                            (
                                f"{cls.__name__}.Params rejects {attribute} = {end} ({reason}); narrow the bounds "
                                "to values it accepts"
                            ),
                        )
                    )
                    break
    if issues:
        raise SpecError(issues, file=source.file)
    return params


def _world(spec: Spec, base: Path | None) -> WorldLayout | None:
    """The spec's MuJoCo world at its nominal placement: its model, workspace boxes and arm."""
    if spec.world is None and spec.workspace is None:
        return None

    def resolved(path: str | None) -> str | None:
        return None if path is None else str(Path(path) if base is None else base / path)

    table, regions = None, ()
    if spec.workspace is not None:
        top = 0.0
        if spec.workspace.table is not None:
            t = spec.workspace.table
            table = Box(name="table", center=t.center, half_size=t.half_size)
            top = t.center[2] + t.half_size[2]
        regions = tuple(
            Box(
                name=r.name,
                center=((r.x[0] + r.x[1]) / 2, (r.y[0] + r.y[1]) / 2, top + 0.001),
                half_size=((r.x[1] - r.x[0]) / 2, (r.y[1] - r.y[0]) / 2, 0.001),
                rgba=REGION_COLOUR,
            )
            for r in spec.workspace.regions
        )
    objects = tuple(
        Box(name=o.name, center=o.position, half_size=o.half_size, rgba=OBJECT_COLOUR) for o in spec.objects
    )
    if spec.world is None:  # a tabletop spec of the paper's kind: the built-in arm
        return WorldLayout(table=table, regions=regions, objects=objects, arm=ArmMount())
    arm = spec.world.arm
    mount = (
        None
        if arm is None
        else ArmMount(
            mjcf=resolved(arm.model),
            ee_site=arm.ee_site,
            base=arm.base,
            yaw=arm.yaw,
            start=None if arm.start is None else tuple(arm.start),
        )
    )
    return WorldLayout(model=resolved(spec.world.model), table=table, regions=regions, objects=objects, arm=mount)


def _nominal_theta(spec: Spec, space: ScenarioSpace, world: WorldLayout | None) -> np.ndarray:
    """Theta of the nominal scenario: each parameter's ``nominal``, else the spec's own value of what
    it binds (an object's position, the arm's pose, a plugin's param), else the middle of its bounds."""
    theta = np.empty(space.dim)
    for slot, p in zip(space.slots, spec.parameters):
        value = p.nominal if p.nominal is not None else _spec_value(slot, space, world)
        if value is None or np.size(value) not in (1, slot.size):
            value = (slot.lower + slot.upper) / 2
        theta[slot.start : slot.start + slot.size] = np.clip(value, slot.lower, slot.upper)
    return theta


def _spec_value(slot: Slot, space: ScenarioSpace, world: WorldLayout | None) -> Any:
    if slot.target in space.nominal_params:
        value = space.nominal_params[slot.target].get(slot.attribute)
        try:
            return None if value is None else np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            return None
    if slot.target in space.nominal_objects:
        return space.nominal_objects[slot.target]["xyz".index(slot.attribute)]
    if slot.target == ARM_TARGET and world is not None and world.arm is not None:
        arm = world.arm
        if slot.attribute == "start":
            return arm.start if arm.start is not None else (START_CONFIG if arm.mjcf is None else None)
        return arm.yaw if slot.attribute == "yaw" else arm.base["xyz".index(slot.attribute)]
    return None  # a body of the world model: the middle of the bounds unless a nominal is given


def _check_world(spec: Spec, world: WorldLayout, scenario: Scenario, source: SourceMap) -> None:
    """Builds the nominal world once, so a missing file, site or body is reported now, not mid-search."""
    from hritest.sim import World

    placed = place(world, scenario)
    if placed.arm is not None:  # the start's length is checked below, against the arm's joints
        placed = replace(placed, arm=replace(placed.arm, start=world.arm.start))
    try:
        built = World(layout=placed)
    except HritestError as exc:
        binding = [
            i
            for i, p in enumerate(spec.parameters)
            if getattr(exc, "body", None) is not None and p.bind.split(".")[0] == exc.body
        ]
        where = ("parameters", binding[0], "bind") if binding else ("world",) if spec.world else ("workspace",)
        raise source.error(where, str(exc)) from None
    joints = len(built.joint_names) if world.arm is not None else 0
    for i, p in enumerate(spec.parameters):
        if p.bind == f"{ARM_TARGET}.start" and p.size != joints:
            raise source.error(
                ("parameters", i, "size"), f"arm.start needs one angle per arm joint: set size: {joints}"
            )
