"""The spec's constraints compiled into one repair step for theta.

Two mechanisms, both from the paper's reference: ``bounds`` clips theta into the parameter
bounds (the teleoperation domain), and ``inside`` / ``no_overlap`` / ``min_separation`` become
the minimum-displacement mixed-integer program of :mod:`hritest.repair` over the objects' x, y
(the collaboration domain). Their costs add up; the search subtracts the total, weighted.

Both measure a displacement in the spec's ``repair.units``: as a fraction of its component's
bounds (``normalised``, so that metres and seconds add up alike), or in the component's own
units (``raw``, the reference's cost, which adds squared metres to squared seconds).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from hritest import repair
from hritest.scenario import ScenarioSpace
from hritest.spec.models import BoundsConstraint, InsideConstraint, MinSeparationConstraint, NoOverlapConstraint, Spec

# CP-SAT's deterministic work limit per repair: enough for the optimal cost on the paper's hardest
# collaboration case (docs/decisions.md); an unproven repair is still used.
REPAIR_WORK_LIMIT = 0.2


@dataclass(frozen=True, kw_only=True)
class RepairOutcome:
    """The repaired theta, what the edit cost, and which region each constrained object is in."""

    theta: np.ndarray
    cost: float
    regions: dict[str, str | None]
    status: str = "ok"
    message: str = ""

    @property
    def ok(self) -> bool:
        return self.status in ("ok", "unchanged", "repaired")


@dataclass(frozen=True, kw_only=True)
class PenaltyTerms:
    """What a smooth stand-in for the repair cost needs: bounds, clip groups, region boxes.

    The surrogate's inner loop cannot call the mixed-integer program hundreds of thousands of
    times, so it penalises theta by (a) the clip cost of the ``bounds`` constraint and (b) each
    placed object's squared distance to its nearest allowed region (overlaps ignored), the
    reference's inner-loop regulariser. ``columns[i]`` are theta's columns of object i's x and y
    (-1: not searched); ``boxes[i, r]`` is region r's ``[[xlo, xhi], [ylo, yhi]]``, NaN where
    object i may not go. ``scale[k]`` is the length that counts as one in component k's
    displacement, as in the repair's cost.
    """

    lower: np.ndarray
    upper: np.ndarray
    clip_groups: list[list[int]] | None
    columns: np.ndarray
    boxes: np.ndarray
    scale: np.ndarray


class ScenarioRepair:
    """Repairs theta so that every constraint of the spec holds, at minimum cost.

    Objects whose x or y is not in theta keep their nominal coordinate: the program may not
    move what the search does not control.
    """

    def __init__(self, *, spec: Spec, space: ScenarioSpace) -> None:
        self._lower, self._upper = space.lower, space.upper
        normalised = spec.repair.units == "normalised"
        self._scale = space.upper - space.lower if normalised else np.ones_like(space.lower)
        self._clip_groups = _clip_groups(spec, space)
        self._problem, self._columns, self._nominal = _program(spec, space, self._scale)

    @property
    def region_names(self) -> tuple[str, ...]:
        return tuple(r.name for r in self._problem.regions) if self._problem else ()

    @property
    def objects(self) -> tuple[str, ...]:
        """The objects the program places (in order); empty when there is no program."""
        return self._problem.object_names if self._problem else ()

    def penalty_terms(self) -> PenaltyTerms:
        columns = self._columns if self._problem else np.zeros((0, 2), dtype=int)
        regions = self._problem.regions if self._problem else ()
        boxes = np.full((len(columns), len(regions), 2, 2), np.nan)
        for i, allowed in enumerate(self._problem.allowed_regions if self._problem else ()):
            for r in allowed:
                boxes[i, r] = (regions[r].x, regions[r].y)
        return PenaltyTerms(
            lower=self._lower,
            upper=self._upper,
            clip_groups=self._clip_groups,
            columns=columns,
            boxes=boxes,
            scale=self._scale,
        )

    def check_feasible(self) -> None:
        """Raises :class:`repair.InfeasibleConstraints` if no scenario satisfies the constraints."""
        if self._problem is not None:
            repair.check_feasible(self._problem)

    def __call__(self, theta: np.ndarray) -> RepairOutcome:
        """The repaired theta. It always lies within the parameters' bounds: without a ``bounds``
        constraint it is clipped into them at no cost, so no plugin ever sees a value outside them."""
        theta = np.asarray(theta, dtype=float).copy()
        cost = 0.0
        if self._clip_groups is not None:
            theta, clip_cost = repair.clip_repair(theta, self._lower, self._upper, self._clip_groups, scale=self._scale)
            cost += float(clip_cost)
        if self._problem is None:
            return RepairOutcome(theta=self._within_bounds(theta), cost=cost, regions={})
        xy = self._nominal.copy()
        bound = self._columns >= 0
        xy[bound] = theta[self._columns[bound]]
        result = repair.repair(self._problem, xy, time_limit=REPAIR_WORK_LIMIT)
        regions = {
            name: (self._problem.regions[index].name if index is not None else None)
            for name, index in zip(self._problem.object_names, result.regions)
        }
        if result.status not in ("unchanged", "repaired"):
            return RepairOutcome(
                theta=theta, cost=cost, regions=regions, status=f"repair_{result.status}", message=result.message
            )
        theta[self._columns[bound]] = result.xy[bound]
        return RepairOutcome(
            theta=self._within_bounds(theta), cost=cost + result.cost, regions=regions, status=result.status
        )

    def _within_bounds(self, theta: np.ndarray) -> np.ndarray:
        # After the placement program (whose own bounds keep what it moves inside), so the
        # paper's repairs are untouched; what is left outside is clipped at no cost.
        return np.clip(theta, self._lower, self._upper)


def _clip_groups(spec: Spec, space: ScenarioSpace) -> list[list[int]] | None:
    """Theta indices of each cost group of the ``bounds`` constraint; None without one."""
    constraints = [c for c in spec.constraints if isinstance(c, BoundsConstraint)]
    if not constraints:
        return None
    slots = {slot.name: slot for slot in space.slots}
    groups: list[list[int]] = []
    grouped: set[str] = set()
    for constraint in constraints:
        for group in constraint.groups:
            groups.append([i for name in group for i in range(slots[name].start, slots[name].start + slots[name].size)])
            grouped.update(group)
    groups += [
        [i] for slot in space.slots if slot.name not in grouped for i in range(slot.start, slot.start + slot.size)
    ]
    return groups


def _program(spec: Spec, space: ScenarioSpace, scale: np.ndarray):  # noqa: ANN202 - (problem, columns, nominal xy)
    placement = [
        c for c in spec.constraints if isinstance(c, InsideConstraint | NoOverlapConstraint | MinSeparationConstraint)
    ]
    if not placement:
        return None, None, None
    names = list(dict.fromkeys(name for c in placement for name in c.objects))
    index = {name: i for i, name in enumerate(names)}
    objects = {o.name: o for o in spec.objects}
    regions = [repair.Region(name=r.name, x=r.x, y=r.y) for r in spec.workspace.regions] if spec.workspace else []
    region_index = {r.name: i for i, r in enumerate(regions)}

    allowed: list[set[int]] = [set() for _ in names]
    no_overlap: set[tuple[int, int]] = set()
    separation: dict[tuple[int, int], float] = {}
    for c in placement:
        members = [index[name] for name in c.objects]
        if isinstance(c, InsideConstraint):
            for i in members:
                allowed[i].update(region_index[r] for r in c.regions)
        elif isinstance(c, NoOverlapConstraint):
            no_overlap.update(itertools.combinations(sorted(members), 2))
        else:
            for pair in itertools.combinations(sorted(members), 2):
                separation[pair] = max(separation.get(pair, 0.0), c.distance)

    # Column of theta holding each object's x and y (-1: not searched, keep nominal).
    columns = -np.ones((len(names), 2), dtype=int)
    bounds = np.empty((len(names), 2, 2))
    scales = np.ones((len(names), 2))  # a coordinate that is not searched never moves: any scale will do
    nominal = np.array([objects[name].position[:2] for name in names], dtype=float)
    for slot in space.slots:
        if slot.target in index and slot.attribute in ("x", "y"):  # the program places in x, y only
            i, axis = index[slot.target], "xy".index(slot.attribute)
            columns[i, axis] = slot.start
            scales[i, axis] = scale[slot.start]
    for i in range(len(names)):
        for axis in range(2):
            searched = columns[i, axis] >= 0
            lo = space.lower[columns[i, axis]] if searched else nominal[i, axis]
            hi = space.upper[columns[i, axis]] if searched else nominal[i, axis]
            bounds[i, axis] = (lo, hi)

    problem = repair.RepairProblem(
        object_names=tuple(names),
        half_sizes=np.array([objects[name].half_size[:2] for name in names], dtype=float),
        regions=tuple(regions),
        allowed_regions=tuple(tuple(sorted(a)) for a in allowed),
        no_overlap=tuple(sorted(no_overlap)),
        min_separation=tuple((i, j, d) for (i, j), d in sorted(separation.items())),
        bounds=bounds,
        scales=scales,
    )
    return problem, columns, nominal
