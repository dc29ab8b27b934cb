"""Whether a placement satisfies a :class:`RepairProblem`, exactly in real arithmetic."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from fractions import Fraction

import numpy as np

from hritest.repair.problem import RepairProblem


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


def _inside(p: np.ndarray, xr: Sequence[float], yr: Sequence[float], tol: float) -> bool:
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
    return any(abs(_exact(xy[i, k]) - _exact(xy[j, k])) >= _exact(hs[i, k]) + _exact(hs[j, k]) for k in range(2))


def _separated(p: np.ndarray, q: np.ndarray, d: float, tol: float) -> bool:
    slack = float(np.hypot(*(p - q))) - d
    if tol > 0 or abs(slack) > 1e-9:
        return slack >= -tol
    dx, dy = _exact(p[0]) - _exact(q[0]), _exact(p[1]) - _exact(q[1])
    return dx * dx + dy * dy >= _exact(d) ** 2


def _exact(value: float) -> Fraction:
    return Fraction(float(value))
