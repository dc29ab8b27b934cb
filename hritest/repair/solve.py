"""Repairs scenario parameters so that object placements satisfy their constraints.

Two repairs, as in the reference (``dsas``):

* :func:`repair` moves object centres as little as possible (sum of squared displacements) so that
  each centre lies in one of its allowed regions and within its bounds, no two footprints overlap
  and separated pairs are far enough apart: the paper's repair MIP, solved with OR-Tools CP-SAT
  on an integer lattice.
* :func:`clip_repair` clips a box-bounded parameter vector (the teleoperation domain).

Everything here is pure computation: no I/O, no printing, no global state.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Iterator, Sequence
from fractions import Fraction

import numpy as np
from ortools.sat.python import cp_model

__all__ = [
    "InfeasibleConstraints",
    "Region",
    "RepairProblem",
    "RepairResult",
    "check_feasible",
    "clip_repair",
    "is_valid",
    "repair",
    "violations",
]

#: The lattice step is 2**-12 m (0.24 mm). A power of two makes every lattice point, and every
#: difference of two, an exact double: valid on the lattice means valid in real coordinates.
#: Measured on the paper's collaboration proposals that need the solver (1 core, interleaved):
#: 2**-11 m: median 10.7 ms, p99 25 ms, cost +1.4e-5 m^2 on average against 2**-13 m;
#: 2**-12 m: 10.3 ms, 28 ms, +2e-6 m^2; 2**-13 m: 11.3 ms, 36 ms. Three piled goals took
#: 0.7 / 1.2 / 2.8 s. 2**-12 keeps the cost within ~1e-5 m^2 of the continuous optimum (the
#: search subtracts it from a time in seconds) at half the tail of 2**-13.
LATTICE_BITS = 12
_SCALE = 2**LATTICE_BITS  # lattice units per metre
#: Objective coefficients are the real ones times 2**10, rounded: the returned lattice point is
#: optimal for the real target up to ~(n + |offset| / 2048) units^2.
_OBJ_SCALE = 2**10
#: Largest |coordinate| in lattice units (512 m): keeps every objective term far below 2**62.
_MAX_UNITS = 2**21


class InfeasibleConstraints(ValueError):
    """No placement of the objects satisfies all of their constraints together."""


@dataclasses.dataclass(frozen=True, kw_only=True)
class Region:
    """An axis-aligned rectangle that an object's centre (not its whole footprint) must lie in.

    Args:
        name: Used in messages.
        x: ``(xlo, xhi)`` bounds of the centre, metres.
        y: ``(ylo, yhi)`` bounds of the centre, metres.

    Raises:
        ValueError: A bound is not finite or ``lo > hi``.
    """

    name: str
    x: tuple[float, float]
    y: tuple[float, float]

    def __post_init__(self) -> None:
        for axis in ("x", "y"):
            lo, hi = (float(v) for v in getattr(self, axis))
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise ValueError(
                    f"region {self.name!r}: {axis} must be (lo, hi) with finite "
                    f"lo <= hi, got {getattr(self, axis)!r}; swap the bounds"
                )
            object.__setattr__(self, axis, (lo, hi))


@dataclasses.dataclass(frozen=True, kw_only=True, eq=False)
class RepairProblem:
    """Objects with axis-aligned footprints and the constraints their centres must satisfy.

    Args:
        object_names: One name per object, used in messages.
        half_sizes: ``(n, 2)`` half extents of each footprint in x and y.
        regions: The rectangles that ``allowed_regions`` indexes.
        allowed_regions: Per object, indices into ``regions``; the centre must lie in at least one
            of them. An empty tuple means no region constraint for that object.
        no_overlap: Pairs whose footprints must not overlap (touching is allowed).
        min_separation: ``(i, j, d)``: the centres of ``i`` and ``j`` are at least ``d`` apart.
        bounds: ``(n, 2, 2)``; ``bounds[i, 0] = (xlo, xhi)`` and ``bounds[i, 1] = (ylo, yhi)``
            bound each centre.

    Raises:
        ValueError: Shapes, indices or values are inconsistent; the message says which.
    """

    object_names: tuple[str, ...]
    half_sizes: np.ndarray
    regions: tuple[Region, ...]
    allowed_regions: tuple[tuple[int, ...], ...]
    no_overlap: tuple[tuple[int, int], ...] = ()
    min_separation: tuple[tuple[int, int, float], ...] = ()
    bounds: np.ndarray

    def __post_init__(self) -> None:
        names = tuple(self.object_names)
        n = len(names)
        if n == 0 or len(set(names)) != n:
            raise ValueError(f"object_names must be non-empty and unique, got {names!r}")
        sizes = _frozen_array(self.half_sizes, (n, 2), "half_sizes")
        if (sizes < 0).any():
            raise ValueError(f"half_sizes must be >= 0, got {sizes.tolist()}")
        bounds = _frozen_array(self.bounds, (n, 2, 2), "bounds")
        if (bounds[:, :, 0] > bounds[:, :, 1]).any():
            raise ValueError("bounds[i, axis] must be (lo, hi) with lo <= hi; swap the bounds")
        allowed = tuple(tuple(int(r) for r in a) for a in self.allowed_regions)
        if len(allowed) != n:
            raise ValueError(f"allowed_regions needs one tuple per object ({n}), got {len(allowed)}")
        if any(not 0 <= r < len(self.regions) for a in allowed for r in a):
            raise ValueError(f"allowed_regions {allowed} index past the {len(self.regions)} regions")
        pairs = tuple((int(i), int(j)) for i, j in self.no_overlap)
        seps = tuple((int(i), int(j), float(d)) for i, j, d in self.min_separation)
        for i, j, *distance in pairs + seps:
            if not (0 <= i < n and 0 <= j < n and i != j):
                raise ValueError(f"pair ({i}, {j}) must name two different objects in 0..{n - 1}")
            if distance and not (math.isfinite(distance[0]) and distance[0] > 0):
                raise ValueError(f"min_separation distance must be > 0, got {distance[0]}")
        for field, value in [
            ("object_names", names),
            ("half_sizes", sizes),
            ("bounds", bounds),
            ("regions", tuple(self.regions)),
            ("allowed_regions", allowed),
            ("no_overlap", pairs),
            ("min_separation", seps),
        ]:
            object.__setattr__(self, field, value)

    @property
    def n(self) -> int:
        """Number of objects."""
        return len(self.object_names)


@dataclasses.dataclass(frozen=True)
class RepairResult:
    """What :func:`repair` did.

    Attributes:
        xy: ``(n, 2)`` repaired centres (the input when nothing could be done).
        cost: Sum of squared displacements in m^2, computed from ``xy``.
        regions: Per object, the index of the region it ends in (``None``: no region constraint,
            or no repair).
        status: ``"unchanged"``, ``"repaired"``, ``"infeasible"``, ``"timeout"`` or ``"error"``.
        message: Human-readable detail; says which stage produced a repair.
    """

    xy: np.ndarray
    cost: float
    regions: tuple[int | None, ...]
    status: str
    message: str = ""


def _frozen_array(value, shape: tuple[int, ...], name: str) -> np.ndarray:
    array = np.array(value, dtype=float)
    if array.shape != shape or not np.isfinite(array).all():
        raise ValueError(f"{name} must be a finite array of shape {shape}, got shape {array.shape}")
    array.setflags(write=False)
    return array


# ---------------------------------------------------------------------------------------------
# Validity
# ---------------------------------------------------------------------------------------------


def is_valid(problem: RepairProblem, xy: np.ndarray, tol: float = 1e-9) -> bool:
    """Whether ``xy`` satisfies every constraint, each within ``tol`` metres.

    With ``tol=0`` the check is exact in real arithmetic on the given doubles: comparisons that
    floating point cannot decide are redone with fractions, so touching boxes count as valid and
    boxes overlapping by 1e-17 do not.
    """
    return next(_violations(problem, np.asarray(xy, dtype=float), tol), None) is None


def violations(problem: RepairProblem, xy: np.ndarray) -> list[str]:
    """Human-readable descriptions of every constraint ``xy`` violates (exact, no tolerance)."""
    return list(_violations(problem, np.asarray(xy, dtype=float), 0.0))


def _violations(problem: RepairProblem, xy: np.ndarray, tol: float) -> Iterator[str]:
    names, b = problem.object_names, problem.bounds
    for i in range(problem.n):
        if not _inside(xy[i], b[i, 0], b[i, 1], tol):
            yield (
                f"{names[i]} at ({xy[i, 0]:.6g}, {xy[i, 1]:.6g}) is outside its bounds "
                f"x in {tuple(b[i, 0])}, y in {tuple(b[i, 1])}"
            )
        if problem.allowed_regions[i] and _region_of(problem, xy, i, tol) is None:
            listed = ", ".join(problem.regions[r].name for r in problem.allowed_regions[i])
            yield f"{names[i]} is outside every allowed region ({listed})"
    for i, j in problem.no_overlap:
        if not _apart(problem, xy, i, j, tol):
            yield f"{names[i]} and {names[j]} overlap"
    for i, j, d in problem.min_separation:
        if not _separated(xy[i], xy[j], d, tol):
            distance = float(np.hypot(*(xy[i] - xy[j])))
            yield f"{names[i]} and {names[j]} are {distance:.6g} m apart, closer than {d:g}"


def _inside(p: np.ndarray, xr, yr, tol: float) -> bool:
    # Comparing doubles is exact: no rescue is needed for tol == 0.
    return xr[0] - tol <= p[0] <= xr[1] + tol and yr[0] - tol <= p[1] <= yr[1] + tol


def _region_of(problem: RepairProblem, xy: np.ndarray, i: int, tol: float = 0.0) -> int | None:
    """The first allowed region containing object ``i``'s centre, or ``None``."""
    for r in problem.allowed_regions[i]:
        if _inside(xy[i], problem.regions[r].x, problem.regions[r].y, tol):
            return r
    return None


def _apart(problem: RepairProblem, xy: np.ndarray, i: int, j: int, tol: float) -> bool:
    """Footprints do not overlap: on some axis ``|p_i - p_j| >= half_i + half_j``."""
    hs = problem.half_sizes
    best = float((np.abs(xy[i] - xy[j]) - hs[i] - hs[j]).max())
    if tol > 0 or abs(best) > 1e-9:
        return best >= -tol
    # Too close to call in floating point (e.g. touching boxes): decide exactly.
    return any(abs(_F(xy[i, k]) - _F(xy[j, k])) >= _F(hs[i, k]) + _F(hs[j, k]) for k in range(2))


def _separated(p: np.ndarray, q: np.ndarray, d: float, tol: float) -> bool:
    slack = float(np.hypot(*(p - q))) - d
    if tol > 0 or abs(slack) > 1e-9:
        return slack >= -tol
    dx, dy = _F(p[0]) - _F(q[0]), _F(p[1]) - _F(q[1])
    return dx * dx + dy * dy >= _F(d) ** 2


def _F(value) -> Fraction:
    return Fraction(float(value))


# ---------------------------------------------------------------------------------------------
# Repair
# ---------------------------------------------------------------------------------------------


def repair(problem: RepairProblem, xy: np.ndarray, *, time_limit: float = 1.0) -> RepairResult:
    """Moves the centres as little as possible (sum of squared displacements) to satisfy every
    constraint: the paper's repair MIP.

    Three stages, cheapest first:

    1. A valid input is returned unchanged, with cost 0, without building a model.
    2. Each object is projected onto its nearest allowed region (intersected with its bounds).
       Without the pairwise constraints the problem is separable and this projection is its
       optimum; when it also satisfies the pairwise constraints it is the exact optimum. On the
       paper's collaboration proposals this settles ~80% of the calls in ~0.1 ms.
    3. Otherwise CP-SAT solves the program on the ``2**-12`` m lattice (one worker, fixed seed,
       deterministic time limit: the same input always gives the same output), hinted with a
       quick push-apart placement. Region and bound limits are rounded inward and footprint sums
       outward, so the result is valid exactly in real coordinates. That rounding costs up to
       ~2 * step * (total displacement) over the continuous optimum (5.7e-6 m^2 for three piled
       goals, whose optimum is 2.9e-3); the solver stops within ``n`` units^2 (n * 6e-8 m^2) of
       its bound. Coordinates that can then move back toward the input without breaking a
       constraint are moved back, so objects that did not need to move stay exactly put.

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
    projected, chosen = _project(xy, boxes)
    if is_valid(problem, projected, tol=0.0):
        regions = [region for region, _, _ in chosen]
        return _result(xy, projected, regions, "projected each object onto its nearest region")
    return _solve(problem, xy, boxes, _push_apart(problem, xy, projected, chosen), time_limit)


def _result(xy0: np.ndarray, xy: np.ndarray, regions, message: str) -> RepairResult:
    return RepairResult(xy, float(((xy - xy0) ** 2).sum()), tuple(regions), "repaired", message)


def _failed(xy: np.ndarray, status: str, message: str) -> RepairResult:
    return RepairResult(xy, 0.0, (None,) * len(xy), status, message)


def _boxes(problem: RepairProblem, i: int) -> list[tuple[int | None, np.ndarray, np.ndarray]]:
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


def _project(xy: np.ndarray, boxes) -> tuple[np.ndarray, list]:
    """Each object clipped into its cheapest box (the first on ties), and those boxes."""
    out, chosen = np.empty_like(xy), []
    for i, candidates in enumerate(boxes):
        clipped = [np.clip(xy[i], lo, hi) for _, lo, hi in candidates]
        best = int(np.argmin([((c - xy[i]) ** 2).sum() for c in clipped]))
        out[i] = clipped[best]
        chosen.append(candidates[best])
    return out, chosen


def _push_apart(problem: RepairProblem, xy0: np.ndarray, xy: np.ndarray, chosen) -> np.ndarray:
    """A quick placement to hint CP-SAT with (it cut the median solve by ~20% and the p99 by
    ~40%): repeatedly take the first violated pair and move both objects apart by half the
    deficit each, within their boxes, on the cheapest side. Not necessarily valid."""
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


def _separate_boxes(problem: RepairProblem, xy0, xy, i: int, j: int, chosen) -> None:
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
            rise = (xi - xy0[i, k]) ** 2 + (xj - xy0[j, k]) ** 2 - (xy[i, k] - xy0[i, k]) ** 2
            moves.append((rise - (xy[j, k] - xy0[j, k]) ** 2, k, xi, xj))
    if moves:
        _, k, xy[i, k], xy[j, k] = min(moves)


# ---------------------------------------------------------------------------------------------
# The lattice program
# ---------------------------------------------------------------------------------------------


class _Model:
    """The repair program on the lattice, in disaggregated (convex hull) form.

    For each box ``b`` object ``i`` may occupy (an allowed region within its bounds): a literal
    ``z_b`` and an offset ``e_b`` from ``P_b``, the box's lattice point nearest the target. The
    centre is ``sum_b P_b z_b + e_b``; ``e_b = 0`` unless ``z_b`` (``OnlyEnforceIf``, the exact
    form of the paper's big-M), restated as ``lo z_b <= e_b <= hi z_b`` (a big-M taken from the
    box itself) so that the LP relaxation sees the region choice. The cost of a box is a constant
    (target to ``P_b``) times ``z_b``, plus ``e_b**2`` with tangent cuts, plus a linear term, so
    the LP bound starts at the projection cost instead of 0. One coordinate variable with a union
    domain and enforced bounds was 2x slower with a >5 s tail: presolve kept it out of the LP.
    """

    def __init__(self, problem: RepairProblem, xy: np.ndarray, boxes, hint: np.ndarray) -> None:
        self.model = cp_model.CpModel()
        self.pos: list[list] = []  # per object and axis: the centre, a linear expression
        self.cost: list[list] = []  # per object and axis: ~_OBJ_SCALE * squared displacement
        self.slack: list[float] = []  # per object: how far below the true cost `cost` may be
        self.choice: list[list[tuple[int | None, cp_model.IntVar]]] = []
        self.target = xy * _SCALE  # exact
        for i, candidates in enumerate(boxes):
            self._add_object(problem.object_names[i], self.target[i], candidates, hint[i] * _SCALE)
        for i, j in problem.no_overlap:
            self._add_pair(i, j, _no_overlap_lines(problem, i, j))
        for i, j, d in problem.min_separation:
            self._add_pair(i, j, _separation_lines(d))
        self.model.minimize(sum(c for costs in self.cost for c in costs))

    def _add_object(self, name: str, target: np.ndarray, candidates, hint: np.ndarray) -> None:
        m, F = self.model, _OBJ_SCALE
        pos, cost, lits, width = [0, 0], [0, 0], [], 0
        hinted = next((b for b, (_, lo, hi) in enumerate(candidates) if _inside(hint / _SCALE, *zip(lo, hi), 0)), 0)
        for b, (region, lo, hi) in enumerate(candidates):
            lattice = _lattice_box(lo, hi)
            if lattice is None:
                continue
            z = m.new_bool_var(f"{name}_in_{region}")
            m.add_hint(z, b == hinted)
            for k in range(2):
                anchor = min(max(round(target[k]), lattice[0][k]), lattice[1][k])
                elo, ehi = lattice[0][k] - anchor, lattice[1][k] - anchor
                width = max(width, ehi - elo)
                e = m.new_int_var(elo, ehi, f"{name}_e{region}{k}")
                m.add_hint(e, min(max(round(hint[k]) - anchor, elo), ehi) if b == hinted else 0)
                m.add(e == 0).only_enforce_if(~z)
                m.add(e >= elo * z)
                m.add(e <= ehi * z)
                sq = m.new_int_var(0, max(elo * elo, ehi * ehi), "")
                m.add_multiplication_equality(sq, [e, e])
                for t in _tangent_points(elo, ehi):
                    m.add(sq >= (2 * t + 1) * e - t * (t + 1))
                offset = anchor - target[k]
                cost[k] += round(F * offset**2) * z + F * sq + round(2 * F * offset) * e
                pos[k] += anchor * z + e
            lits.append((region, z))
        if not lits:
            raise _NoLatticePoint(name)
        m.add_exactly_one([z for _, z in lits])
        self.pos.append(pos)
        self.cost.append(cost)
        # Rounding the coefficients moves each axis' cost by at most (1 + |e|) / 2.
        self.slack.append((1 + width) / 2)
        self.choice.append(lits)

    def _add_pair(self, i: int, j: int, lines: list[tuple[tuple[int, int], int]]) -> None:
        """At least one of ``lines`` holds; plus lower bounds on the pair's cost.

        Meeting ``u . (p_j - p_i) >= R`` moves the pair by at least the shortfall along ``u``,
        split evenly at best (boxes ignored, so always valid). Tied to each line's literal (and,
        for the many circle lines, also as their minimum, or the LP spreads the literals thinly)
        this puts a pair cost into the LP bound, which otherwise sees only separate projections.
        It made hard random instances 3-10x faster.
        """
        sides = _separating_lines(self.model, self.pos[i], self.pos[j], lines)
        pair_cost = [self.cost[i][k] + self.cost[j][k] for k in range(2)]
        delta, slack, least = self.target[j] - self.target[i], self.slack[i] + self.slack[j], []
        for (u, rhs), side in zip(lines, sides):
            short = max(rhs - u[0] * delta[0] - u[1] * delta[1], 0) / math.hypot(*u)
            axes = [k for k in range(2) if u[k]]
            bound = math.floor(_OBJ_SCALE * short**2 / 2 - len(axes) * slack)
            if bound > 0:
                self.model.add(sum(pair_cost[k] for k in axes) >= bound * side)
            least.append(short)
        bound = math.floor(_OBJ_SCALE * min(least) ** 2 / 2 - 2 * slack)
        if len(lines) > 4 and bound > 0:
            self.model.add(pair_cost[0] + pair_cost[1] >= bound)


class _NoLatticePoint(Exception):
    pass


def _lattice_box(lo: np.ndarray, hi: np.ndarray) -> tuple[list[int], list[int]] | None:
    """Inward rounding: ``x * 2**k`` is exact in floating point, so ``ceil`` and ``floor`` round
    the true bounds. ``None`` if no lattice point fits."""
    lo_units, hi_units = [math.ceil(v * _SCALE) for v in lo], [math.floor(v * _SCALE) for v in hi]
    return None if any(a > b for a, b in zip(lo_units, hi_units)) else (lo_units, hi_units)


def _tangent_points(lo: int, hi: int) -> list[int]:
    """Where to cut ``sq >= e**2`` from below: 0 and powers of two out to the domain's ends.

    ``sq >= (2t + 1) e - t (t + 1)`` is exact at ``e = t`` and ``t + 1``. CP-SAT derives such cuts
    itself, one LP round at a time; stating them up front (and ``cut_level=0``) was ~25% faster.
    """
    points, step = [0], 1
    while step < max(-lo, hi):
        points += [t for t in (-step, step) if lo <= t <= hi]
        step *= 2
    return points


def _separating_lines(m: cp_model.CpModel, p, q, lines, enforce=()) -> list:
    """``OR over (u, R) in lines of u . (q - p) >= R``, enforced by ``enforce``; the literals."""
    sides = [m.new_bool_var("") for _ in lines]
    for (u, rhs), side in zip(lines, sides):
        m.add(sum(u[k] * (q[k] - p[k]) for k in range(2) if u[k]) >= rhs).only_enforce_if(side)
    m.add_bool_or(sides).only_enforce_if(list(enforce))
    return sides


def _no_overlap_lines(problem: RepairProblem, i: int, j: int) -> list[tuple[tuple[int, int], int]]:
    """``j`` right of, left of, above or below ``i``. The lattice gap is the exact sum of the two
    half sizes (as fractions of the doubles) rounded up, so touching on the lattice is apart."""
    hs = problem.half_sizes
    reach = [math.ceil((_F(hs[i, k]) + _F(hs[j, k])) * _SCALE) for k in range(2)]
    return [((1, 0), reach[0]), ((-1, 0), reach[0]), ((0, 1), reach[1]), ((0, -1), reach[1])]


#: Primitive integer directions with components up to 3: 32 of them, at most 18.4 degrees apart.
#: Small components matter: lattice points on ``u . delta = R`` are ``|u|`` units apart, so each
#: line's lattice optimum is close to its continuous one. With ~1000-unit directions CP-SAT took
#: seconds for one pair.
_DIRECTIONS = sorted(
    {(a, b) for a in range(-3, 4) for b in range(-3, 4) if math.gcd(a, b) == 1}, key=lambda u: math.atan2(u[1], u[0])
)


def _separation_lines(d: float) -> list[tuple[tuple[int, int], int]]:
    """``u . delta >= R`` with ``R >= d |u|`` (exactly, in lattice units) implies ``|delta| >= d``
    (Cauchy-Schwarz): any one of these lines keeps the centres far enough apart. Together they
    bound a 32-gon no wider than ``d / cos(9.2 deg) = 1.013 d``."""
    lines = []
    for u in _DIRECTIONS:
        need = math.ceil(_F(d) ** 2 * _SCALE**2 * (u[0] ** 2 + u[1] ** 2))  # R**2 >= need
        rhs = math.isqrt(need)
        lines.append((u, rhs if rhs * rhs >= need else rhs + 1))
    return lines


def _solve(problem: RepairProblem, xy: np.ndarray, boxes, hint, time_limit: float) -> RepairResult:
    extent = max([np.abs(xy).max()] + [np.abs([lo, hi]).max() for b in boxes for _, lo, hi in b])
    if extent * _SCALE > _MAX_UNITS:
        return _failed(
            xy,
            "error",
            f"coordinates beyond {_MAX_UNITS / _SCALE:g} m do not fit "
            "the repair lattice; express positions in metres near the origin",
        )
    try:
        built = _Model(problem, xy, boxes, hint)
        solver = _solver(time_limit, problem.n, bool(problem.min_separation))
        status = solver.solve(built.model)
    except _NoLatticePoint as exc:
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
    # Measured on the paper's instance: quick restarts plus LP relaxations of the enforced
    # constraints halved the median solve (31 -> 15 ms) and cut the p99 from >5 s to ~60 ms.
    params.search_branching = cp_model.PORTFOLIO_WITH_QUICK_RESTART_SEARCH
    params.linearization_level = 2
    params.cut_level = 0
    # Stop within n units^2 of the bound: closing the last sliver took most of the time.
    params.absolute_gap_limit = _OBJ_SCALE * n_objects
    if circles:
        params.relative_gap_limit = 0.01
    return solver


def _extract(problem: RepairProblem, xy0, boxes, built: _Model, solver) -> RepairResult:
    xy = np.array([[solver.value(p) / _SCALE for p in pos] for pos in built.pos])
    regions = [next(r for r, z in lits if solver.boolean_value(z)) for lits in built.choice]
    chosen = [next(box for box in boxes[i] if box[0] == r) for i, r in enumerate(regions)]
    xy = _polish(problem, xy0, xy, chosen)
    if not is_valid(problem, xy, tol=0.0):  # defensive: never hand back an invalid repair
        return _failed(
            xy0, "error", "internal error: the lattice solution violates " + "; ".join(violations(problem, xy))
        )
    return _result(xy0, xy, regions, f"CP-SAT optimum on the 2**-{LATTICE_BITS} m lattice")


def _polish(problem: RepairProblem, xy0, xy, chosen) -> np.ndarray:
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


# ---------------------------------------------------------------------------------------------
# Feasibility
# ---------------------------------------------------------------------------------------------


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


def _feasibility_model(problem: RepairProblem):
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


def _add_box(m: cp_model.CpModel, pos, lo, hi, enforce) -> None:
    """``lo <= pos <= hi``, rounded inward to the lattice, enforced by ``enforce``."""
    for k in range(2):
        m.add(pos[k] >= math.ceil(lo[k] * _SCALE)).only_enforce_if(enforce)
        m.add(pos[k] <= math.floor(hi[k] * _SCALE)).only_enforce_if(enforce)


# ---------------------------------------------------------------------------------------------
# Box-only domains
# ---------------------------------------------------------------------------------------------


def clip_repair(
    theta: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    groups: Sequence[Sequence[int]] | None = None,
) -> tuple[np.ndarray, float]:
    """Clips ``theta`` into ``[lo, hi]`` and returns the reference's clipping cost.

    The cost is the reference's definition (``clip_one_ws`` in ``dsas``): per group of components,
    the excesses (distance outside the bounds, >= 0) are summed, the sum is squared, and the
    squares are added. Groups exist to reproduce that number, which is not a sum of squares: the
    teleoperation domain groups the goals' x coordinates, their y coordinates and the waypoint
    noises, giving ``(sum e_x)^2 + (sum e_y)^2 + (sum e_noise)^2``. ``groups=None``, or a
    component listed in no group, makes each component its own group (a plain sum of squares).

    Args:
        theta: ``(d,)`` or ``(batch, d)``.
        lo: ``(d,)`` lower bounds.
        hi: ``(d,)`` upper bounds.
        groups: Disjoint lists of component indices.

    Returns:
        The clipped ``theta`` (same shape) and the cost, of shape ``()`` or ``(batch,)``.

    Raises:
        ValueError: Shapes disagree, ``lo > hi``, or a group index is out of range or repeated.
    """
    theta = np.asarray(theta, dtype=float)
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    d = theta.shape[-1] if theta.ndim else -1
    if theta.ndim not in (1, 2) or lo.shape != (d,) or hi.shape != (d,):
        raise ValueError(
            f"theta must be (d,) or (batch, d) with lo and hi of shape (d,); got "
            f"{theta.shape}, {lo.shape} and {hi.shape}"
        )
    if (lo > hi).any():
        raise ValueError(f"lo must be <= hi; components {np.flatnonzero(lo > hi).tolist()} are not")
    excess = np.maximum(lo - theta, 0.0) + np.maximum(theta - hi, 0.0)
    cost = ((excess @ _membership(groups, d).T) ** 2).sum(axis=-1)
    return np.clip(theta, lo, hi), cost[()] if theta.ndim == 1 else cost


def _membership(groups: Sequence[Sequence[int]] | None, d: int) -> np.ndarray:
    """``(n_groups, d)`` 0/1 matrix; unlisted components become groups of their own."""
    rows, seen = [], set()
    for g in groups or ():
        g = [int(k) for k in g]
        if any(not 0 <= k < d for k in g) or seen & set(g) or len(set(g)) != len(g):
            raise ValueError(f"groups must be disjoint lists of indices in 0..{d - 1}, got {groups}")
        seen |= set(g)
        rows.append(np.isin(np.arange(d), g).astype(float))
    rows += [np.eye(d)[k] for k in range(d) if k not in seen]
    return np.array(rows).reshape(-1, d)
