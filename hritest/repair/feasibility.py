"""Whether any placement satisfies a :class:`RepairProblem`, and if not, which constraints conflict."""

from __future__ import annotations

import math
from collections.abc import Sequence

from ortools.sat.python import cp_model

from hritest.repair.lattice import _SCALE, _no_overlap_lines, _separating_lines, _separation_lines
from hritest.repair.problem import InfeasibleConstraints, RepairProblem


def check_feasible(problem: RepairProblem, *, time_limit: float = 1.0) -> None:
    """Raises if no placement satisfies all constraints, naming a small set that conflicts.

    Each constraint group (an object's bounds, its region constraint, a no-overlap pair, a
    separation pair) gets an assumption literal. CP-SAT's infeasible core is then shrunk by
    deletion filtering (drop one group; keep it dropped while the rest stay infeasible), so every
    group named is needed for the conflict. Feasibility is decided on the repair lattice, i.e.
    for the placements :func:`repair` can return. Undecided within ``time_limit`` counts as
    feasible: a conflict is never reported unproven.

    Raises:
        InfeasibleConstraints: With a message listing the conflicting constraints.
    """
    model, groups = _feasibility_model(problem)
    core = _core(model, [lit for lit, _ in groups], time_limit)
    if core is None:
        return
    for lit in list(core):
        if any(other is lit for other in core):  # (``in`` would build a CP-SAT constraint)
            smaller = _core(model, [other for other in core if other is not lit], time_limit)
            core = core if smaller is None else smaller
    label = {lit.index: text for lit, text in groups}
    raise InfeasibleConstraints(
        f"no placement of {', '.join(problem.object_names)} satisfies these constraints together: "
        f"{'; '.join(label[lit.index] for lit in core)}. Relax one of them (a larger or another "
        "region, smaller objects, wider bounds or a shorter separation)."
    )


def _core(model: cp_model.CpModel, assumptions: list, time_limit: float) -> list | None:
    """A subset of ``assumptions`` that cannot hold together, or ``None`` if all of them can (or
    CP-SAT cannot tell within the limit)."""
    model.clear_assumptions()
    model.add_assumptions(assumptions)
    solver = cp_model.CpSolver()
    solver.parameters.num_workers = 1
    solver.parameters.max_deterministic_time = time_limit
    if solver.solve(model) != cp_model.INFEASIBLE:
        return None
    found = set(solver.sufficient_assumptions_for_infeasibility())
    return [lit for lit in assumptions if lit.index in found] or list(assumptions)


def _feasibility_model(problem: RepairProblem) -> tuple[cp_model.CpModel, list[tuple[cp_model.IntVar, str]]]:
    """Every constraint group enforced by its own literal, on a lattice wide enough that dropping
    the bounds never leaves the objects short of room."""
    m, names, groups = cp_model.CpModel(), problem.object_names, []
    room = 2 * problem.half_sizes.max() * problem.n + sum(d for *_, d in problem.min_separation)
    limits = [problem.bounds.min(), problem.bounds.max()]
    limits += [v for region in problem.regions for v in (*region.x, *region.y)]
    lo, hi = math.floor((min(limits) - room) * _SCALE), math.ceil((max(limits) + room) * _SCALE)
    pos = [[m.new_int_var(lo, hi, f"{name}_{axis}") for axis in "xy"] for name in names]

    def group(text: str) -> cp_model.IntVar:
        lit = m.new_bool_var(text)
        groups.append((lit, text))
        return lit

    for i, name in enumerate(names):
        b = problem.bounds[i]
        _add_box(m, pos[i], b[:, 0], b[:, 1], group(f"{name} within its bounds x in {tuple(b[0])}, y in {tuple(b[1])}"))
        if problem.allowed_regions[i]:
            listed = " or ".join(problem.regions[r].name for r in problem.allowed_regions[i])
            inside = [m.new_bool_var("") for _ in problem.allowed_regions[i]]
            for r, z in zip(problem.allowed_regions[i], inside):
                region = problem.regions[r]
                _add_box(m, pos[i], (region.x[0], region.y[0]), (region.x[1], region.y[1]), z)
            m.add_bool_or(inside).only_enforce_if(group(f"{name} inside {listed}"))
    for i, j in problem.no_overlap:
        lit = group(f"{names[i]} and {names[j]} do not overlap")
        _separating_lines(m, pos[i], pos[j], _no_overlap_lines(problem, i, j), [lit])
    for i, j, d in problem.min_separation:
        lit = group(f"{names[i]} and {names[j]} at least {d:g} m apart")
        _separating_lines(m, pos[i], pos[j], _separation_lines(d), [lit])
    return m, groups


def _add_box(
    m: cp_model.CpModel,
    pos: list[cp_model.IntVar],
    lo: Sequence[float],
    hi: Sequence[float],
    enforce: cp_model.IntVar | Sequence[cp_model.IntVar],
) -> None:
    """``lo <= pos <= hi``, rounded inward to the lattice, enforced by ``enforce``."""
    for k in range(2):
        m.add(pos[k] >= math.ceil(lo[k] * _SCALE)).only_enforce_if(enforce)
        m.add(pos[k] <= math.floor(hi[k] * _SCALE)).only_enforce_if(enforce)
