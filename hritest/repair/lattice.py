"""The repair program on the integer lattice, in CP-SAT: its scale, the model and its constraint lines.

Working on a lattice of step ``2**-LATTICE_BITS`` m is what makes a solver's answer valid exactly in
real coordinates (``docs/decisions.md``, "The repair lattice").
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from ortools.sat.python import cp_model

from hritest.repair.problem import RepairProblem
from hritest.repair.validity import _exact, _inside

#: The lattice step is 2**-12 m (0.24 mm). A power of two makes every lattice point, and every
#: difference of two, an exact double: valid on the lattice means valid in real coordinates.
#: Why this step and not another: docs/decisions.md, "The repair lattice".
LATTICE_BITS = 12
_SCALE = 2**LATTICE_BITS  # lattice units per metre
#: Objective coefficients are the real ones times 2**10, rounded: the returned lattice point is
#: optimal for the real target up to ~(n + |offset| / 2048) units^2. With scales (a cost in other
#: units than metres) the widest scale's coordinates keep exactly this factor (:func:`_weights`).
_OBJ_SCALE = 2**10
#: Largest |coordinate| in lattice units (512 m): keeps every objective term far below 2**62.
_MAX_UNITS = 2**21

#: Where an object's centre may go: ``(region, lo, hi)``, an allowed region (``None``: no region
#: constraint) intersected with the object's bounds.
Box = tuple[int | None, np.ndarray, np.ndarray]
#: ``(u, R)``: the constraint ``u . (q - p) >= R`` between two centres, in lattice units.
Line = tuple[tuple[int, int], int]


class _Model:
    """The repair program on the lattice, in disaggregated (convex hull) form.

    For each box ``b`` object ``i`` may occupy (an allowed region within its bounds): a literal
    ``z_b`` and an offset ``e_b`` from ``P_b``, the box's lattice point nearest the target. The
    centre is ``sum_b P_b z_b + e_b``; ``e_b = 0`` unless ``z_b`` (``OnlyEnforceIf``, the exact
    form of the paper's big-M), restated as ``lo z_b <= e_b <= hi z_b`` (a big-M taken from the
    box itself) so that the LP relaxation sees the region choice. The cost of a box is a constant
    (target to ``P_b``) times ``z_b``, plus ``e_b**2`` with tangent cuts, plus a linear term, so
    the LP bound starts at the projection cost instead of 0 (docs/decisions.md, "The repair
    program's form"). Each object's axis weighs its squared displacement by its integer weight
    (:func:`_weights`).
    """

    def __init__(self, problem: RepairProblem, xy: np.ndarray, boxes: list[list[Box]], hint: np.ndarray) -> None:
        self.model = cp_model.CpModel()
        self.pos: list[list] = []  # per object and axis: the centre, a linear expression
        self.cost: list[list] = []  # per object and axis: ~weight * squared displacement
        self.slack: list[float] = []  # per object: how far below the true cost `cost` may be
        self.choice: list[list[tuple[int | None, cp_model.IntVar]]] = []
        self.target = xy * _SCALE  # exact
        self.weights = _weights(problem.scales)
        for i, candidates in enumerate(boxes):
            self._add_object(problem.object_names[i], self.target[i], candidates, hint[i] * _SCALE, self.weights[i])
        for i, j in problem.no_overlap:
            self._add_pair(i, j, _no_overlap_lines(problem, i, j))
        for i, j, d in problem.min_separation:
            self._add_pair(i, j, _separation_lines(d))
        self.model.minimize(sum(c for costs in self.cost for c in costs))

    def _add_object(
        self, name: str, target: np.ndarray, candidates: list[Box], hint: np.ndarray, weights: list[int]
    ) -> None:
        m = self.model
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
                offset, weight = anchor - target[k], weights[k]
                cost[k] += round(weight * offset**2) * z + weight * sq + round(2 * weight * offset) * e
                pos[k] += anchor * z + e
            lits.append((region, z))
        if not lits:
            raise _NoLatticePointError(name)
        m.add_exactly_one([z for _, z in lits])
        self.pos.append(pos)
        self.cost.append(cost)
        # Rounding the coefficients moves each axis' cost by at most (1 + |e|) / 2.
        self.slack.append((1 + width) / 2)
        self.choice.append(lits)

    def _add_pair(self, i: int, j: int, lines: list[Line]) -> None:
        """At least one of ``lines`` holds; plus lower bounds on the pair's cost.

        Meeting ``u . (p_j - p_i) >= R`` moves the pair by at least the shortfall along ``u``,
        split evenly at best (boxes ignored, so always valid), at the least weight of the axes it
        moves along. Tied to each line's literal (and, for the many circle lines, also as their
        minimum, or the LP spreads the literals thinly) this puts a pair cost into the LP bound,
        which otherwise sees only separate projections.
        """
        sides = _separating_lines(self.model, self.pos[i], self.pos[j], lines)
        pair_cost = [self.cost[i][k] + self.cost[j][k] for k in range(2)]
        delta, slack, least = self.target[j] - self.target[i], self.slack[i] + self.slack[j], []
        lightest = [min(self.weights[i][k], self.weights[j][k]) for k in range(2)]
        for (u, rhs), side in zip(lines, sides):
            short = max(rhs - u[0] * delta[0] - u[1] * delta[1], 0) / math.hypot(*u)
            axes = [k for k in range(2) if u[k]]
            bound = math.floor(min(lightest[k] for k in axes) * short**2 / 2 - len(axes) * slack)
            if bound > 0:
                self.model.add(sum(pair_cost[k] for k in axes) >= bound * side)
            least.append(short)
        bound = math.floor(min(lightest) * min(least) ** 2 / 2 - 2 * slack)
        if len(lines) > 4 and bound > 0:
            self.model.add(pair_cost[0] + pair_cost[1] >= bound)


class _NoLatticePointError(Exception):
    pass


def _weights(scales: np.ndarray) -> list[list[int]]:
    """The objective's integer weight of each object's axis: ``_OBJ_SCALE * (widest / scale)**2``,
    rounded. The widest scale weighs exactly ``_OBJ_SCALE`` (all of them, for the paper's cost in
    m^2), and no weight less, so no coefficient loses precision; the rounding moves the others'
    ratios by at most 1 in 2048."""
    return [[round(_OBJ_SCALE * (scales.max() / s) ** 2) for s in row] for row in scales]


def _reach(scales: np.ndarray) -> float:
    """The largest |coordinate| (m) whose objective terms fit CP-SAT's 64 bits at these scales."""
    return _MAX_UNITS / _SCALE * scales.min() / scales.max()


def _lattice_box(lo: np.ndarray, hi: np.ndarray) -> tuple[list[int], list[int]] | None:
    """Inward rounding: ``x * 2**k`` is exact in floating point, so ``ceil`` and ``floor`` round
    the true bounds. ``None`` if no lattice point fits."""
    lo_units, hi_units = [math.ceil(v * _SCALE) for v in lo], [math.floor(v * _SCALE) for v in hi]
    return None if any(a > b for a, b in zip(lo_units, hi_units)) else (lo_units, hi_units)


def _tangent_points(lo: int, hi: int) -> list[int]:
    """Where to cut ``sq >= e**2`` from below: 0 and powers of two out to the domain's ends.

    ``sq >= (2t + 1) e - t (t + 1)`` is exact at ``e = t`` and ``t + 1``. CP-SAT derives such cuts
    itself, one LP round at a time; stating them up front (with ``cut_level=0``) is faster.
    """
    points, step = [0], 1
    while step < max(-lo, hi):
        points += [t for t in (-step, step) if lo <= t <= hi]
        step *= 2
    return points


def _separating_lines(
    m: cp_model.CpModel, p: list, q: list, lines: list[Line], enforce: Sequence[cp_model.IntVar] = ()
) -> list:
    """``OR over (u, R) in lines of u . (q - p) >= R``, enforced by ``enforce``; the literals."""
    sides = [m.new_bool_var("") for _ in lines]
    for (u, rhs), side in zip(lines, sides):
        m.add(sum(u[k] * (q[k] - p[k]) for k in range(2) if u[k]) >= rhs).only_enforce_if(side)
    m.add_bool_or(sides).only_enforce_if(list(enforce))
    return sides


def _no_overlap_lines(problem: RepairProblem, i: int, j: int) -> list[Line]:
    """``j`` right of, left of, above or below ``i``. The lattice gap is the exact sum of the two
    half sizes (as fractions of the doubles) rounded up, so touching on the lattice is apart."""
    hs = problem.half_sizes
    reach = [math.ceil((_exact(hs[i, k]) + _exact(hs[j, k])) * _SCALE) for k in range(2)]
    return [((1, 0), reach[0]), ((-1, 0), reach[0]), ((0, 1), reach[1]), ((0, -1), reach[1])]


#: Primitive integer directions with components up to 3: 32 of them, at most 18.4 degrees apart.
#: Small components matter: lattice points on ``u . delta = R`` are ``|u|`` units apart, so each
#: line's lattice optimum is close to its continuous one.
_DIRECTIONS = sorted(
    {(a, b) for a in range(-3, 4) for b in range(-3, 4) if math.gcd(a, b) == 1}, key=lambda u: math.atan2(u[1], u[0])
)


def _separation_lines(d: float) -> list[Line]:
    """``u . delta >= R`` with ``R >= d |u|`` (exactly, in lattice units) implies ``|delta| >= d``
    (Cauchy-Schwarz): any one of these lines keeps the centres far enough apart. Together they
    bound a 32-gon no wider than ``d / cos(9.2 deg) = 1.013 d``."""
    lines = []
    for u in _DIRECTIONS:
        need = math.ceil(_exact(d) ** 2 * _SCALE**2 * (u[0] ** 2 + u[1] ** 2))  # R**2 >= need
        rhs = math.isqrt(need)
        lines.append((u, rhs if rhs * rhs >= need else rhs + 1))
    return lines
