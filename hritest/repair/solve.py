"""The minimum-displacement repair: unchanged, projected, or solved on the lattice with CP-SAT."""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence

import numpy as np
from ortools.sat.python import cp_model

from hritest.repair.lattice import _OBJ_SCALE, _SCALE, LATTICE_BITS, Box, _Model, _NoLatticePointError, _reach
from hritest.repair.problem import RepairProblem, RepairResult
from hritest.repair.validity import _apart, _region_of, _separated, is_valid, violations


def repair(problem: RepairProblem, xy: np.ndarray, *, time_limit: float = 1.0) -> RepairResult:
    """Moves the centres as little as possible (sum of squared displacements, each over its
    ``problem.scales``) to satisfy every constraint: the paper's repair MIP.

    Three stages, cheapest first:

    1. A valid input is returned unchanged, with cost 0, without building a model.
    2. Each object is projected onto its nearest allowed region (intersected with its bounds).
       Without the pairwise constraints the problem is separable and this projection is its
       optimum; when it also satisfies the pairwise constraints it is the exact optimum.
    3. Otherwise CP-SAT solves the program on the ``2**-12`` m lattice (one worker, fixed seed,
       deterministic time limit: the same input always gives the same output), hinted with a
       quick push-apart placement. Region and bound limits are rounded inward and footprint sums
       outward, so the result is valid exactly in real coordinates. That rounding costs up to
       ~2 * step * (total displacement) over the continuous optimum; the solver stops within
       ``n`` units^2 (n * 6e-8 m^2) of its bound. Coordinates that can then move back toward the
       input without breaking a constraint are moved back, so objects that did not need to move
       stay exactly put.

    ``min_separation`` is enforced through 32 supporting lines of the circle (any one implies
    the distance; the polygon is at most 1.3% wider than the circle) and solved to within 1% of
    the bound: CP-SAT cannot prove a lattice optimum next to a circle in useful time.

    Args:
        problem: The objects and constraints.
        xy: ``(n, 2)`` proposed centres.
        time_limit: CP-SAT's deterministic time limit, its machine-independent work measure
            (roughly seconds of one core for long solves; solves of a few ms are mostly setup and
            use far less). A work limit keeps results reproducible even when it is hit.

    Returns:
        The repaired centres, their cost and a status. An infeasible problem, a timeout or a
        solver failure is reported in ``status`` with the input ``xy`` and cost 0 (a valid repair found
        but not proven optimal at the time limit is returned as "repaired"); this function
        does not raise for them.

    Raises:
        ValueError: ``xy`` does not have shape ``(n, 2)`` or is not finite.
    """
    xy = np.array(xy, dtype=float)
    if xy.shape != (problem.n, 2) or not np.isfinite(xy).all():
        raise ValueError(f"xy must be a finite array of shape ({problem.n}, 2), got {xy.shape}")
    if is_valid(problem, xy, tol=0.0):
        regions = tuple(_region_of(problem, xy, i) for i in range(problem.n))
        return RepairResult(xy, 0.0, regions, "unchanged", "input satisfies every constraint")
    boxes = [_boxes(problem, i) for i in range(problem.n)]
    if any(not b for b in boxes):
        return _failed(
            xy,
            "infeasible",
            "an object's allowed regions all lie outside its bounds; run check_feasible(problem) to see which",
        )
    projected, chosen = _project(xy, boxes, problem.scales)
    if is_valid(problem, projected, tol=0.0):
        regions = [region for region, _, _ in chosen]
        return _result(problem, xy, projected, regions, "projected each object onto its nearest region")
    return _solve(problem, xy, boxes, _push_apart(problem, xy, projected, chosen), time_limit)


def _result(
    problem: RepairProblem, xy0: np.ndarray, xy: np.ndarray, regions: Sequence[int | None], message: str
) -> RepairResult:
    return RepairResult(xy, float((((xy - xy0) / problem.scales) ** 2).sum()), tuple(regions), "repaired", message)


def _failed(xy: np.ndarray, status: str, message: str) -> RepairResult:
    return RepairResult(xy, 0.0, (None,) * len(xy), status, message)


def _boxes(problem: RepairProblem, i: int) -> list[Box]:
    """Where object ``i``'s centre may go: ``(region, lo, hi)`` for each allowed region
    intersected with its bounds (non-empty ones only), or just its bounds (region ``None``)."""
    b = problem.bounds[i]
    if not problem.allowed_regions[i]:
        return [(None, b[:, 0], b[:, 1])]
    boxes = []
    for r in problem.allowed_regions[i]:
        region = problem.regions[r]
        lo = np.maximum(b[:, 0], [region.x[0], region.y[0]])
        hi = np.minimum(b[:, 1], [region.x[1], region.y[1]])
        if (lo <= hi).all():
            boxes.append((r, lo, hi))
    return boxes


def _project(xy: np.ndarray, boxes: list[list[Box]], scales: np.ndarray) -> tuple[np.ndarray, list[Box]]:
    """Each object clipped into its cheapest box (the first on ties), and those boxes."""
    out, chosen = np.empty_like(xy), []
    for i, candidates in enumerate(boxes):
        clipped = [np.clip(xy[i], lo, hi) for _, lo, hi in candidates]
        best = int(np.argmin([(((c - xy[i]) / scales[i]) ** 2).sum() for c in clipped]))
        out[i] = clipped[best]
        chosen.append(candidates[best])
    return out, chosen


def _push_apart(problem: RepairProblem, xy0: np.ndarray, xy: np.ndarray, chosen: list[Box]) -> np.ndarray:
    """A quick placement to hint CP-SAT with: repeatedly take the first violated pair and move both
    objects apart by half the deficit each, within their boxes, on the cheapest side. Not
    necessarily valid."""
    xy = xy.copy()
    for _ in range(4 * problem.n**2):
        pairs = [(i, j) for i, j in problem.no_overlap if not _apart(problem, xy, i, j, 1e-12)]
        seps = [(i, j, d) for i, j, d in problem.min_separation if not _separated(xy[i], xy[j], d, 1e-12)]
        if pairs:
            _separate_boxes(problem, xy0, xy, *pairs[0], chosen)
        elif seps:
            i, j, d = seps[0]
            gap = xy[j] - xy[i]
            norm = float(np.hypot(*gap))
            step = (gap / norm if norm > 0 else np.array([1.0, 0.0])) * (d - norm) / 2
            xy[i] = np.clip(xy[i] - step, chosen[i][1], chosen[i][2])
            xy[j] = np.clip(xy[j] + step, chosen[j][1], chosen[j][2])
        else:
            break
    return xy


def _separate_boxes(problem: RepairProblem, xy0: np.ndarray, xy: np.ndarray, i: int, j: int, chosen: list[Box]) -> None:
    """Moves ``i`` and ``j`` apart (in place) along the cheapest of the four sides; when one
    meets the edge of its box the other takes the rest of the move."""
    moves = []
    for k, sign in itertools.product(range(2), (1, -1)):
        deficit = problem.half_sizes[i, k] + problem.half_sizes[j, k] - sign * (xy[j, k] - xy[i, k])
        lo, hi = [c[1][k] for c in chosen], [c[2][k] for c in chosen]
        xi = min(max(xy[i, k] - sign * deficit / 2, lo[i]), hi[i])
        xj = min(max(xy[j, k] + sign * deficit - (xy[i, k] - xi), lo[j]), hi[j])
        xi = xy[i, k] - sign * deficit + (xj - xy[j, k])
        if lo[i] <= xi <= hi[i]:
            si, sj = problem.scales[i, k] ** 2, problem.scales[j, k] ** 2
            rise = (xi - xy0[i, k]) ** 2 / si + (xj - xy0[j, k]) ** 2 / sj - (xy[i, k] - xy0[i, k]) ** 2 / si
            moves.append((rise - (xy[j, k] - xy0[j, k]) ** 2 / sj, k, xi, xj))
    if moves:
        _, k, xy[i, k], xy[j, k] = min(moves)


def _solve(
    problem: RepairProblem, xy: np.ndarray, boxes: list[list[Box]], hint: np.ndarray, time_limit: float
) -> RepairResult:
    extent = max([np.abs(xy).max()] + [np.abs([lo, hi]).max() for b in boxes for _, lo, hi in b])
    if extent > _reach(problem.scales):
        return _failed(
            xy,
            "error",
            f"coordinates beyond {_reach(problem.scales):g} m do not fit "
            "the repair lattice; express positions in metres near the origin",
        )
    try:
        built = _Model(problem, xy, boxes, hint)
        solver = _solver(time_limit, problem.n, bool(problem.min_separation))
        status = solver.solve(built.model)
    except _NoLatticePointError as exc:
        return _failed(
            xy,
            "infeasible",
            f"no allowed region of {exc} contains a point of the 2**-{LATTICE_BITS} m repair lattice; widen it",
        )
    except Exception as exc:
        return _failed(xy, "error", f"CP-SAT failed: {exc!r}")
    if status == cp_model.OPTIMAL:
        return _extract(problem, xy, boxes, built, solver)
    if status == cp_model.INFEASIBLE:
        return _failed(
            xy,
            "infeasible",
            "no placement satisfies the constraints; run check_feasible(problem) to see which conflict",
        )
    if status == cp_model.FEASIBLE:
        # A valid repair that is merely unproven is far more use to a search than a failed scenario.
        found = _extract(problem, xy, boxes, built, solver)
        return dataclasses.replace(
            found,
            message=f"the best repair CP-SAT found within its deterministic time limit "
            f"{time_limit:g}; not proven optimal",
        )
    if status == cp_model.UNKNOWN:
        return _failed(
            xy,
            "timeout",
            f"CP-SAT reached its deterministic time limit {time_limit:g} before finding a repair; input returned",
        )
    return _failed(xy, "error", f"CP-SAT returned {solver.status_name(status)}")


def _solver(time_limit: float, n_objects: int, circles: bool) -> cp_model.CpSolver:
    solver = cp_model.CpSolver()
    params = solver.parameters
    params.num_workers = 1
    params.random_seed = 0
    params.max_deterministic_time = float(time_limit)
    # Quick restarts and LP relaxations of the enforced constraints keep the tail of solve times
    # short (docs/decisions.md, "CP-SAT's settings for the repair").
    params.search_branching = cp_model.PORTFOLIO_WITH_QUICK_RESTART_SEARCH
    params.linearization_level = 2
    params.cut_level = 0
    # Stop within n units^2 of the bound: closing the last sliver took most of the time.
    params.absolute_gap_limit = _OBJ_SCALE * n_objects
    if circles:
        params.relative_gap_limit = 0.01
    return solver


def _extract(
    problem: RepairProblem, xy0: np.ndarray, boxes: list[list[Box]], built: _Model, solver: cp_model.CpSolver
) -> RepairResult:
    xy = np.array([[solver.value(p) / _SCALE for p in pos] for pos in built.pos])
    regions = [next(r for r, z in lits if solver.boolean_value(z)) for lits in built.choice]
    chosen = [next(box for box in boxes[i] if box[0] == r) for i, r in enumerate(regions)]
    xy = _polish(problem, xy0, xy, chosen)
    if not is_valid(problem, xy, tol=0.0):  # defensive: never hand back an invalid repair
        return _failed(
            xy0, "error", "internal error: the lattice solution violates " + "; ".join(violations(problem, xy))
        )
    return _result(problem, xy0, xy, regions, f"CP-SAT optimum on the 2**-{LATTICE_BITS} m lattice")


def _polish(problem: RepairProblem, xy0: np.ndarray, xy: np.ndarray, chosen: list[Box]) -> np.ndarray:
    """Moves each coordinate to the point of its box nearest the input where that keeps every
    constraint. Each accepted move brings a coordinate closer to its target, so the cost never
    rises, and objects that did not need to move end exactly where they were."""
    xy = xy.copy()
    for i, (_, lo, hi) in enumerate(chosen):
        for k in range(2):
            goal = min(max(xy0[i, k], lo[k]), hi[k])
            if goal != xy[i, k]:
                before, xy[i, k] = xy[i, k], goal
                if not is_valid(problem, xy, tol=0.0):
                    xy[i, k] = before
    return xy
