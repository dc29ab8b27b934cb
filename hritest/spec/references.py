"""Checks that need the whole spec: names that refer to other names, sizes that must agree.

Each check returns issues with the exact field path, so the message can point at the line.
"""

from __future__ import annotations

import ast
import keyword
import math
from collections.abc import Collection, Iterator

from hritest.sim.layout import ARM_ATTRIBUTES, BODY_ATTRIBUTES
from hritest.spec import expr
from hritest.spec.models import BoundsConstraint, Spec

AGENT_TARGETS = ("human", "robot", "task")
ARM_TARGET = "arm"
OBJECT_ATTRIBUTES = ("x", "y", "z")

# Sizes beyond which a search cannot start: the archives hold every cell up front (several
# arrays of theta's length each), and each CMA-ES emitter a covariance of theta's length squared.
MAX_CELLS = 1_000_000
MAX_DIM = 1_000

Found = Iterator[tuple[tuple[str | int, ...], str]]


def check_references(spec: Spec, *, metrics: Collection[str] | None = None) -> list[tuple[tuple, str]]:
    """Every cross-reference problem in ``spec`` as ``(path, message)`` pairs.

    Args:
        metrics: the metric names the task provides; ``None`` skips the expression-name check
            (the task plugin is not loaded yet).
    """
    found = [*_duplicates(spec), *_bindings(spec), *_constraints(spec), *_archive(spec), *_search(spec), *_sizes(spec)]
    found += [*_unusable_names(spec), *_indices(spec)]
    if metrics is not None:
        found += [*_shadowed_metrics(spec, set(metrics)), *_expression_names(spec, set(metrics))]
    return found


def _duplicates(spec: Spec) -> Found:
    groups = {
        "regions": [r.name for r in regions(spec)],
        "objects": [o.name for o in spec.objects],
    }
    for field, names in groups.items():
        seen: set[str] = set()
        for i, name in enumerate(names):
            if name in seen:
                path = ("workspace", "regions", i, "name") if field == "regions" else (field, i, "name")
                yield path, f"duplicate name {name!r}: every entry of {field} needs its own name"
            seen.add(name)
    # Parameters and measures share one namespace: both may appear in expressions.
    seen = {"objective"}
    for field, items in (("parameters", spec.parameters), ("measures", spec.measures)):
        for i, item in enumerate(items):
            if item.name in seen:
                yield (
                    (field, i, "name"),
                    (
                        f"duplicate name {item.name!r}: parameter and measure names must be unique "
                        "and may not be 'objective'"
                    ),
                )
            seen.add(item.name)


def has_arm(spec: Spec) -> bool:
    """Whether the spec's world has a robot arm: ``world.arm``, or the built-in one of a tabletop spec."""
    return spec.world.arm is not None if spec.world is not None else spec.workspace is not None


def regions(spec: Spec) -> list:
    return spec.workspace.regions if spec.workspace is not None else []


def _bindings(spec: Spec) -> Found:
    objects = {o.name for o in spec.objects}
    model = spec.world.model if spec.world is not None else None
    bound: dict[str, int] = {}
    for i, param in enumerate(spec.parameters):
        head, attribute = param.bind.split(".")
        path = ("parameters", i, "bind")
        if head in AGENT_TARGETS:
            pass  # checked against the plugin's Params when the spec is compiled
        elif head == ARM_TARGET:
            if not has_arm(spec):
                yield path, f"{param.bind!r} binds the robot arm, but this spec has none; add world.arm"
            elif attribute not in ARM_ATTRIBUTES:
                yield path, f"the arm's bindable attributes are {', '.join(ARM_ATTRIBUTES)}, not {attribute!r}"
            elif attribute != "start" and param.size != 1:
                yield ("parameters", i, "size"), f"{param.bind!r} is one number; remove 'size' or set it to 1"
        elif head in objects:
            if attribute not in OBJECT_ATTRIBUTES:
                yield (
                    path,
                    (
                        f"an object parameter binds {', '.join(f'{head}.{a}' for a in OBJECT_ATTRIBUTES)}, "
                        f"not {param.bind!r}"
                    ),
                )
            elif param.size != 1:
                yield ("parameters", i, "size"), f"{param.bind!r} is one number; remove 'size' or set it to 1"
        elif model is not None:  # a body of the world model: its name is checked against the model file
            if attribute not in BODY_ATTRIBUTES:
                yield path, (f"a body of the world model binds {', '.join(BODY_ATTRIBUTES)}, not {attribute!r}")
            elif param.size != 1:
                yield ("parameters", i, "size"), f"{param.bind!r} is one number; remove 'size' or set it to 1"
        else:
            known = ", ".join(sorted(objects) + list(AGENT_TARGETS) + ([ARM_TARGET] if has_arm(spec) else []))
            yield (
                path,
                (
                    f"unknown target {head!r} in {param.bind!r}; bind to one of: {known} "
                    "(or to a body of a world model named in world.model)"
                ),
            )
        if param.bind in bound:
            yield path, f"{param.bind!r} is already bound by parameters[{bound[param.bind]}]"
        bound.setdefault(param.bind, i)
    for i, obj in enumerate(spec.objects):
        if obj.name in AGENT_TARGETS or obj.name == ARM_TARGET:
            yield ("objects", i, "name"), f"{obj.name!r} is reserved for a bind target; rename the object"


def _constraints(spec: Spec) -> Found:
    objects = {o.name for o in spec.objects}
    region_names = {r.name for r in regions(spec)}
    parameters = {p.name for p in spec.parameters}
    for i, constraint in enumerate(spec.constraints):
        for j, name in enumerate(getattr(constraint, "objects", [])):
            if name not in objects:
                known = ", ".join(sorted(objects)) or "none: add them under objects"
                yield ("constraints", i, "objects", j), f"unknown object {name!r}; the objects are {known}"
        for j, name in enumerate(getattr(constraint, "regions", [])):
            if name not in region_names:
                known = ", ".join(sorted(region_names)) or "none: add them under workspace.regions"
                yield ("constraints", i, "regions", j), f"unknown region {name!r}; the regions are {known}"
        if isinstance(constraint, BoundsConstraint):
            for j, group in enumerate(constraint.groups):
                for k, name in enumerate(group):
                    if name not in parameters:
                        yield ("constraints", i, "groups", j, k), f"unknown parameter {name!r}"


def _search(spec: Spec) -> Found:
    dim = sum(p.size for p in spec.parameters)
    x0 = spec.search.emitter.x0
    if x0 is not None and len(x0) != dim:
        yield ("search", "emitter", "x0"), f"has {len(x0)} values but theta has {dim} components"
    me_x0 = spec.search.map_elites.x0
    if me_x0 is not None and len(me_x0) != dim:
        yield ("search", "map_elites", "x0"), f"has {len(me_x0)} values but theta has {dim} components"
    sigma = spec.search.map_elites.sigma
    if isinstance(sigma, list) and len(sigma) != dim:
        yield (
            ("search", "map_elites", "sigma"),
            (f"has {len(sigma)} values but theta has {dim} components; give one number or {dim}"),
        )
    cells = spec.search.surrogate.downsample_cells
    if cells is not None and spec.archive.type == "cvt":
        if len(cells) != 1 or cells[0] > (spec.archive.cells or 0):
            yield (
                ("search", "surrogate", "downsample_cells"),
                f"with a cvt archive, give one number of selection cells, at most the archive's {spec.archive.cells}",
            )
    elif cells is not None:
        if len(cells) != len(spec.measures):
            yield (
                ("search", "surrogate", "downsample_cells"),
                (f"has {len(cells)} values, one per measure is needed ({len(spec.measures)})"),
            )
        for i, (n, measure) in enumerate(zip(cells, spec.measures)):
            if measure.cells is not None and n > measure.cells:
                yield (
                    ("search", "surrogate", "downsample_cells", i),
                    (f"{n} cells is more than measure {measure.name!r} has ({measure.cells})"),
                )


def _expression_names(spec: Spec, metrics: set[str]) -> Found:
    parameters = {p.name for p in spec.parameters}
    measures = {m.name for m in spec.measures}
    numeric_scope = metrics | parameters
    checks = [(("objective", "expr"), spec.objective.expr, numeric_scope, False)]
    checks += [(("measures", i, "expr"), m.expr, numeric_scope, False) for i, m in enumerate(spec.measures)]
    checks.append((("failure",), spec.failure, numeric_scope | measures | {"objective"}, True))
    for path, text, scope, condition in checks:
        unknown = sorted(expr.parse(text, condition=condition).names - scope)
        if unknown:
            yield (
                path,
                (
                    f"unknown name{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))}; "
                    f"known here: {', '.join(sorted(scope))}"
                ),
            )


def _sizes(spec: Spec) -> Found:
    dim = sum(p.size for p in spec.parameters)
    if dim > MAX_DIM:
        yield (
            ("parameters",),
            f"theta has {dim:,} components; a search handles at most {MAX_DIM:,}: reduce the parameters' sizes",
        )
    if spec.archive.type == "cvt":
        return
    cells = math.prod(m.cells or 1 for m in spec.measures)
    if cells > MAX_CELLS:
        product = " x ".join(f"{m.cells:,}" for m in spec.measures)
        yield (
            ("measures",),
            f"the archive would have {product} = {cells:,} cells; at most {MAX_CELLS:,} fit in memory: "
            "reduce the measures' cells",
        )


def _archive(spec: Spec) -> Found:
    """A grid needs each measure's cells and at most two measures; a cvt archive its own cells."""
    if spec.archive.type == "cvt":
        if spec.archive.cells is None:
            yield ("archive",), "a cvt archive needs its number of cells: archive: {type: cvt, cells: 1000}"
        for i, m in enumerate(spec.measures):
            if m.cells is not None:
                yield (
                    ("measures", i, "cells"),
                    "a cvt archive has no cells per measure: remove it (archive.cells counts)",
                )
        return
    if len(spec.measures) > 2:
        yield (
            ("measures",),
            f"{len(spec.measures)} measures need a cvt archive (a grid's cells grow as a power of the measures): add "
            "archive: {type: cvt, cells: 1000} and remove the measures' cells",
        )
    for i, m in enumerate(spec.measures):
        if m.cells is None:
            yield ("measures", i, "cells"), "a grid archive needs each measure's number of cells, e.g. cells: 20"
    if spec.archive.cells is not None:
        yield ("archive", "cells"), "a grid archive's cells are each measure's cells: remove archive.cells"


def _unusable_names(spec: Spec) -> Found:
    """Names that an expression cannot refer to: Python keywords and the expression functions."""
    for field, items in (("parameters", spec.parameters), ("measures", spec.measures)):
        for i, item in enumerate(items):
            if keyword.iskeyword(item.name) or item.name in expr.FUNCTIONS:
                what = "a Python keyword" if keyword.iskeyword(item.name) else "a function of expressions"
                yield (field, i, "name"), f"{item.name!r} is {what}, so no expression can refer to it; rename it"


def _shadowed_metrics(spec: Spec, metrics: set[str]) -> Found:
    """Names that hide a metric: in an expression the name would mean the parameter or measure, silently.

    A measure that is the metric itself (``{name: speed, expr: speed}``) hides nothing.
    """
    for i, param in enumerate(spec.parameters):
        if param.name in metrics:
            yield (
                ("parameters", i, "name"),
                (
                    f"parameter {param.name!r} has the name of the task's metric {param.name!r} ({spec.task.name}); "
                    "in expressions the parameter would hide the metric: rename the parameter"
                ),
            )
    for i, measure in enumerate(spec.measures):
        if measure.name in metrics and measure.expr.strip() != measure.name:
            yield (
                ("measures", i, "name"),
                (
                    f"measure {measure.name!r} ({measure.expr}) has the name of the task's metric {measure.name!r} "
                    f"({spec.task.name}); in the failure condition the measure would hide the metric: rename the "
                    "measure"
                ),
            )


def _indices(spec: Spec) -> Found:
    """Indexes that no scenario can satisfy: past a parameter group's end, or into a single number."""
    sizes = {p.name: p.size for p in spec.parameters} | {m.name: 1 for m in spec.measures} | {"objective": 1}
    texts = [(("objective", "expr"), spec.objective.expr, False)]
    texts += [(("measures", i, "expr"), m.expr, False) for i, m in enumerate(spec.measures)]
    texts.append((("failure",), spec.failure, True))
    for path, text, condition in texts:
        for node in ast.walk(expr.parse(text, condition=condition).tree):
            if not isinstance(node, ast.Subscript):
                continue
            name, index = node.value.id, node.slice.value
            size = sizes.get(name)
            if size is None:
                continue  # a metric, or a name that does not exist: both checked once the task is known
            if size == 1:
                yield path, f"{name!r} is one number, not a group: write {name}, not {ast.unparse(node)}"
            elif index >= size:
                yield (
                    path,
                    f"{ast.unparse(node)} is past the end of {name!r}, which has {size} components: "
                    f"{name}[0] to {name}[{size - 1}]",
                )
