"""Tests for hritest.repair: optimality against brute force, validity, properties, failures."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import hritest.repair as repair_module
import hritest.repair.solve as solve_module
from hritest.repair import (
    InfeasibleConstraints,
    Region,
    RepairProblem,
    check_feasible,
    clip_repair,
    is_valid,
    repair,
    violations,
)

HALF = 0.025
Q = 2.0**-repair_module.LATTICE_BITS  # the repair lattice step, m


def collaboration(n: int = 3) -> RepairProblem:
    """The paper's collaboration instance: goals inside ws1 or ws2, pairwise not overlapping."""
    ws = [("ws1", (0.6, 0.05)), ("ws2", (0.218, 0.626))]
    return RepairProblem(
        object_names=tuple(f"goal{i}" for i in range(n)),
        half_sizes=np.full((n, 2), HALF),
        regions=tuple(Region(name=m, x=(c[0] - 0.08, c[0] + 0.08), y=(c[1] - 0.13, c[1] + 0.13)) for m, c in ws),
        allowed_regions=((0, 1),) * n,
        no_overlap=tuple(itertools.combinations(range(n), 2)),
        bounds=np.tile([-1 + HALF, 1 - HALF], (n, 2, 1)),
    )


PAPER = collaboration()


# ---------------------------------------------------------------------------------------------
# Optimality against exhaustive search
# ---------------------------------------------------------------------------------------------
#
# Every constant of these instances (region corners, bounds, half sizes) is a multiple of
# G = 1/16 m, and G is a multiple of the repair lattice step Q, so the lattice needs no rounding.
# Take a continuous optimum p* (cost c*) and, per axis, its region choice and which side each pair
# is separated on. Those constraints read lo <= x_i <= hi and x_j - x_i >= c with integer lo, hi,
# c (in units of G). z = floor(x / G + theta), with one theta in [0, 1) per axis, keeps all of
# them (floor is monotone and floor(u + c) = floor(u) + c for integer c), so z is a feasible
# lattice placement. Averaged over theta, the rounding error r of a coordinate has E[r] = 0 and
# E[r^2] = f(1 - f) <= 1/4 (f its fractional part), so E[cost(z)] <= c* + 2n * G^2 / 4 and some
# theta gives
#     c* <= c_bf <= c* + n * G^2 / 2,
# with c_bf the optimum over the G lattice. The same argument on the Q lattice bounds the
# repair's lattice optimum by c* + n Q^2 / 2. CP-SAT stops within n Q^2 of its bound, and its
# integer objective approximates the real one to (n + |e|_1) / 2048 Q^2 per solution, with
# |e|_1 <= 2n W (W: the width of the world in Q units). Polishing only lowers the cost, and a
# valid repair costs >= c*. Hence
#     -n G^2 / 2  <=  c_rep - c_bf  <=  Q^2 * (n / 2 + n + (2n + 4n W) / 2048).

G = 1 / 16
U = 8  # the world is [-U, U] * G on both axes


def random_instance(rng: np.random.Generator) -> tuple[RepairProblem, np.ndarray]:
    while True:
        n, n_regions = int(rng.integers(2, 5)), int(rng.integers(1, 4))
        regions = []
        for r in range(n_regions):
            lo = rng.integers(-U, U - 1, size=2)
            hi = np.minimum(lo + rng.integers(1, 6, size=2), U)
            regions.append(Region(name=f"r{r}", x=(lo[0] * G, hi[0] * G), y=(lo[1] * G, hi[1] * G)))
        allowed = tuple(
            ()
            if rng.random() < 0.15
            else tuple(sorted(rng.choice(n_regions, rng.integers(1, n_regions + 1), replace=False)))
            for _ in range(n)
        )
        problem = RepairProblem(
            object_names=tuple(f"o{i}" for i in range(n)),
            half_sizes=rng.integers(1, 3, size=(n, 2)) * G,
            regions=tuple(regions),
            allowed_regions=allowed,
            no_overlap=tuple(p for p in itertools.combinations(range(n), 2) if rng.random() < 0.8),
            bounds=np.tile([-U * G, U * G], (n, 2, 1)),
        )
        if _has_witness(problem, rng):
            break
    xy = rng.uniform(-(U + 1) * G, (U + 1) * G, size=(n, 2))
    for i in range(1, n):  # pile objects up: the hard case for the solver
        if rng.random() < 0.5:
            xy[i] = xy[rng.integers(i)] + rng.normal(0, 0.2 * G, size=2)
    return problem, xy


def _candidates(problem: RepairProblem, i: int) -> np.ndarray:
    """Integer G-lattice points (in units of G) where object i's centre may go."""
    boxes = [(problem.bounds[i, :, 0], problem.bounds[i, :, 1])]
    if problem.allowed_regions[i]:
        boxes = [
            (
                np.maximum(boxes[0][0], [problem.regions[r].x[0], problem.regions[r].y[0]]),
                np.minimum(boxes[0][1], [problem.regions[r].x[1], problem.regions[r].y[1]]),
            )
            for r in problem.allowed_regions[i]
        ]
    axes = [[np.arange(round(a / G), round(b / G) + 1) for a, b in zip(lo, hi)] for lo, hi in boxes]
    points = [np.stack(np.meshgrid(*ax, indexing="ij"), -1).reshape(-1, 2) for ax in axes]
    return np.unique(np.concatenate(points), axis=0)


def _has_witness(problem: RepairProblem, rng: np.random.Generator) -> bool:
    """Random sequential placement on the G lattice: a cheap proof that the instance is feasible."""
    for _ in range(50):
        placed = []
        for i in range(problem.n):
            options = [
                p
                for p in _candidates(problem, i)
                if all(
                    (np.abs(p - q) * G >= problem.half_sizes[i] + problem.half_sizes[j]).any()
                    for j, q in enumerate(placed)
                    if (j, i) in problem.no_overlap
                )
            ]
            if not options:
                break
            placed.append(options[rng.integers(len(options))])
        else:
            return True
    return False


def brute_force(problem: RepairProblem, xy: np.ndarray, upper: float) -> float:
    """The cheapest G-lattice placement costing at most ``upper`` (inf if none): a vectorised
    join over objects, pruned by cost (each object's own minimum bounds the rest)."""
    points = [_candidates(problem, i) for i in range(problem.n)]
    costs = [((p * G - xy[i]) ** 2).sum(1) for i, p in enumerate(points)]
    floor = [c.min() for c in costs]
    keep = [c + sum(floor) - f <= upper for c, f in zip(costs, floor)]
    points = [p[k] for p, k in zip(points, keep)]
    costs = [c[k] for c, k in zip(costs, keep)]
    order = np.argsort([len(p) for p in points])
    chosen, total = np.arange(len(points[order[0]]))[:, None], costs[order[0]]
    for depth, o in enumerate(order[1:], start=1):
        rest = sum(floor[k] for k in order[depth + 1 :])
        ok = total[:, None] + costs[o][None, :] + rest <= upper
        for slot, placed in enumerate(order[:depth]):
            if (min(placed, o), max(placed, o)) in problem.no_overlap:
                reach = np.rint((problem.half_sizes[placed] + problem.half_sizes[o]) / G)
                gap = np.abs(points[placed][chosen[:, slot]][:, None, :] - points[o][None, :, :])
                ok &= (gap >= reach).any(-1)
        rows, cols = np.nonzero(ok)
        chosen = np.concatenate([chosen[rows], cols[:, None]], axis=1)
        total = total[rows] + costs[o][cols]
    return float(total.min()) if len(total) else float("inf")


@pytest.mark.parametrize("seed", range(40))
def test_repair_matches_brute_force(seed):
    problem, xy = random_instance(np.random.default_rng(seed))
    result = repair(problem, xy)
    assert result.status in ("repaired", "unchanged"), result.message
    assert is_valid(problem, result.xy, tol=0.0), violations(problem, result.xy)
    assert result.cost == pytest.approx(((result.xy - xy) ** 2).sum(), abs=1e-15)
    n, width = problem.n, 2 * U * G / Q
    slack_down = n * G**2 / 2
    slack_up = Q**2 * (n / 2 + n + (2 * n + 4 * n * width) / 2048)
    best = brute_force(problem, xy, result.cost + slack_down + 1e-12)
    assert best <= result.cost + slack_down + 1e-12  # else the brute force missed a placement
    assert result.cost <= best + slack_up + 1e-12  # the repair is optimal


def test_min_separation_splits_the_move():
    problem = RepairProblem(
        object_names=("a", "b"),
        half_sizes=np.zeros((2, 2)),
        regions=(),
        allowed_regions=((), ()),
        min_separation=((0, 1, 0.1),),
        bounds=np.tile([-1.0, 1.0], (2, 2, 1)),
    )
    result = repair(problem, np.array([[0.3, 0.2], [0.3, 0.2]]))
    assert result.status == "repaired"
    assert is_valid(problem, result.xy, tol=0.0)
    # Each moves half of 0.1 (cost 0.005); CP-SAT stops within 1% of its bound near a circle,
    # and moving along x on the lattice needs the distance rounded up to a lattice step.
    assert 2 * 0.05**2 <= result.cost <= 1.01 * (np.ceil(0.1 / Q) * Q) ** 2 / 2


# ---------------------------------------------------------------------------------------------
# The paper's collaboration instance
# ---------------------------------------------------------------------------------------------


def test_piled_goals_are_separated_at_minimal_cost():
    # Continuous optimum for gap r: two goals side by side (each moved r/2 in x), the third above
    # them (y offsets r/3, r/3 and 2r/3): 7 r^2 / 6, i.e. 7/2400 m^2 for r = 0.05. On the lattice
    # the gap rounds up to r_q; that placement is valid, and the lattice adds at most n Q^2 / 2
    # plus CP-SAT's stopping gap n Q^2 (see the brute-force test).
    result = repair(PAPER, np.tile([0.6, 0.05], (3, 1)), time_limit=20)
    assert result.status == "repaired", result.message
    assert is_valid(PAPER, result.xy, tol=0.0)
    assert result.regions == (0, 0, 0)
    r_q = np.ceil(2 * HALF / Q) * Q
    assert 7 / 2400 <= result.cost <= 7 * r_q**2 / 6 + 2 * 3 * Q**2


def test_far_goal_goes_to_the_nearest_region():
    xy = np.array([[0.6, 0.05], [0.218, 0.626], [0.9, 0.9]])
    result = repair(PAPER, xy)
    assert result.status == "repaired"
    assert result.regions == (0, 1, 1)
    np.testing.assert_array_equal(result.xy[2], [0.298, 0.756])  # ws2's nearest corner
    np.testing.assert_array_equal(result.xy[:2], xy[:2])
    assert result.cost == pytest.approx((0.9 - 0.298) ** 2 + (0.9 - 0.756) ** 2, rel=1e-12)


def test_far_goal_beside_an_occupant_needs_the_solver():
    xy = np.array([[0.6, 0.05], [0.25, 0.74], [0.25, 1.0]])
    result = repair(PAPER, xy)
    assert result.status == "repaired" and "CP-SAT" in result.message
    assert result.regions[2] == 1
    assert is_valid(PAPER, result.xy, tol=0.0)
    assert result.xy[0].tolist() == xy[0].tolist()  # the uninvolved goal does not move


def test_repair_is_deterministic():
    xy = np.array([[0.30, 0.60], [0.31, 0.61], [0.29, 0.62]])
    first, second = repair(PAPER, xy), repair(PAPER, xy)
    assert first.status == "repaired"
    np.testing.assert_array_equal(first.xy, second.xy)
    assert (first.cost, first.regions) == (second.cost, second.regions)


# ---------------------------------------------------------------------------------------------
# Properties
# ---------------------------------------------------------------------------------------------

coordinate = st.floats(-0.2, 1.0, allow_nan=False)
any_xy = st.lists(st.tuples(coordinate, coordinate), min_size=3, max_size=3).map(np.array)


@st.composite
def valid_xy(draw):
    xy = []
    for _ in range(PAPER.n):
        region = PAPER.regions[draw(st.integers(0, 1))]
        xy.append([draw(st.floats(*region.x)), draw(st.floats(*region.y))])
    xy = np.array(xy)
    assume(is_valid(PAPER, xy, tol=0.0))
    return xy


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(valid_xy())
def test_valid_input_is_returned_unchanged(xy):
    result = repair(PAPER, xy)
    assert result.status == "unchanged" and result.cost == 0.0
    np.testing.assert_array_equal(result.xy, xy)
    assert all(
        r is not None and PAPER.regions[r].x[0] <= p[0] <= PAPER.regions[r].x[1] for r, p in zip(result.regions, xy)
    )


@settings(max_examples=30, deadline=None)
@given(any_xy)
def test_repair_is_idempotent_and_costs_what_it_moves(xy):
    # Hypothesis likes equal coordinates, i.e. exactly piled goals, which can take CP-SAT
    # seconds (see the pile test); a short limit keeps this test fast and skips those.
    first = repair(PAPER, xy, time_limit=0.2)
    assume(first.status != "timeout")
    assert first.status in ("unchanged", "repaired")
    assert first.cost >= 0.0
    assert first.cost == pytest.approx(((first.xy - xy) ** 2).sum(), abs=1e-15)
    again = repair(PAPER, first.xy)
    assert again.status == "unchanged" and again.cost == 0.0
    np.testing.assert_array_equal(again.xy, first.xy)


@st.composite
def clip_case(draw):
    d = draw(st.integers(1, 9))
    batch = draw(st.integers(1, 4))
    lo = np.array(draw(st.lists(st.floats(-1, 1), min_size=d, max_size=d)))
    hi = lo + np.array(draw(st.lists(st.floats(0, 1), min_size=d, max_size=d)))
    theta = np.array(draw(st.lists(st.lists(st.floats(-3, 3), min_size=d, max_size=d), min_size=batch, max_size=batch)))
    order = draw(st.permutations(range(d)))
    cuts = sorted(draw(st.sets(st.integers(1, d), max_size=3)))
    groups = [order[a:b] for a, b in zip([0] + cuts, cuts + [d]) if order[a:b]]
    groups = draw(st.one_of(st.none(), st.just(groups[:-1]), st.just(groups)))
    return theta, lo, hi, groups


@settings(max_examples=200, deadline=None)
@given(clip_case())
def test_clip_repair_matches_the_grouped_definition(case):
    theta, lo, hi, groups = case
    clipped, cost = clip_repair(theta, lo, hi, groups)
    assert cost.shape == (len(theta),)
    listed = {k for g in groups or () for k in g}
    for row, c, out in zip(theta, cost, clipped):
        excess = [max(lo[k] - row[k], 0.0) + max(row[k] - hi[k], 0.0) for k in range(len(row))]
        expected = sum(sum(excess[k] for k in g) ** 2 for g in groups or ())
        expected += sum(excess[k] ** 2 for k in range(len(row)) if k not in listed)
        assert c == pytest.approx(expected, rel=1e-12, abs=1e-12)
        assert ((lo <= out) & (out <= hi)).all()
        one, one_cost = clip_repair(row, lo, hi, groups)
        assert one_cost.shape == () and one_cost == pytest.approx(c, rel=1e-12, abs=1e-12)
        np.testing.assert_array_equal(one, out)


def test_clip_repair_reference_example():
    # Teleoperation: goals' x, goals' y and the five noises are three groups.
    lo = np.array([0.52, -0.08, 0.52, -0.08] + [-0.05] * 5)
    hi = np.array([0.68, 0.18, 0.68, 0.18] + [0.05] * 5)
    theta = np.array([0.70, 0.0, 0.71, 0.0, 0.06, 0, 0, 0, -0.07])
    groups = [[0, 2], [1, 3], [4, 5, 6, 7, 8]]
    _, cost = clip_repair(theta, lo, hi, groups)
    assert cost == pytest.approx((0.02 + 0.03) ** 2 + (0.01 + 0.02) ** 2)


# ---------------------------------------------------------------------------------------------
# Feasibility and failures
# ---------------------------------------------------------------------------------------------


def crowded(n: int = 4) -> RepairProblem:
    """Four objects of half-size 0.1 whose centres must share one 0.1 x 0.1 region."""
    return RepairProblem(
        object_names=tuple(f"box{i}" for i in range(n)),
        half_sizes=np.full((n, 2), 0.1),
        regions=(Region(name="tray", x=(0.0, 0.1), y=(0.0, 0.1)),),
        allowed_regions=((0,),) * n,
        no_overlap=tuple(itertools.combinations(range(n), 2)),
        bounds=np.tile([-1.0, 1.0], (n, 2, 1)),
    )


def test_check_feasible_names_a_minimal_conflict():
    with pytest.raises(InfeasibleConstraints) as info:
        check_feasible(crowded())
    message = str(info.value)
    # Any two boxes conflict with the tray: the minimal set is two "inside" and their pair.
    assert message.count("inside tray") == 2 and message.count("do not overlap") == 1
    assert "within its bounds" not in message


def test_check_feasible_names_bounds_that_exclude_a_region():
    problem = RepairProblem(
        object_names=("cup",),
        half_sizes=np.zeros((1, 2)),
        regions=(Region(name="shelf", x=(2.0, 3.0), y=(0.0, 1.0)),),
        allowed_regions=((0,),),
        bounds=np.tile([-1.0, 1.0], (1, 2, 1)),
    )
    with pytest.raises(InfeasibleConstraints, match=r"cup within its bounds.*cup inside shelf"):
        check_feasible(problem)
    assert repair(problem, np.zeros((1, 2))).status == "infeasible"


def test_check_feasible_passes_on_the_paper_instance():
    check_feasible(PAPER)


def test_infeasible_repair_is_a_status():
    xy = np.full((4, 2), 0.05)
    result = repair(crowded(), xy)
    assert result.status == "infeasible" and "check_feasible" in result.message
    np.testing.assert_array_equal(result.xy, xy)


def test_timeout_is_a_status():
    xy = np.tile([0.6, 0.05], (3, 1))
    result = repair(PAPER, xy, time_limit=1e-9)
    assert result.status == "timeout"
    np.testing.assert_array_equal(result.xy, xy)


def test_solver_failure_is_a_status(monkeypatch):
    class Broken:
        def solve(self, model):
            raise RuntimeError("solver crashed")

    monkeypatch.setattr(solve_module, "_solver", lambda *args: Broken())
    result = repair(PAPER, np.tile([0.6, 0.05], (3, 1)))
    assert result.status == "error" and "solver crashed" in result.message


def test_violations_are_readable():
    xy = np.array([[0.6, 0.05], [0.61, 0.05], [0.0, 0.0]])
    assert violations(PAPER, xy) == [
        "goal2 is outside every allowed region (ws1, ws2)",
        "goal0 and goal1 overlap",
    ]
    assert not is_valid(PAPER, xy)


def test_touching_is_decided_exactly():
    # The smallest double y1 with y1 - 0.6 >= 0.025 + 0.025 in exact arithmetic touches; one ulp
    # less overlaps by ~1e-17, which floating-point subtraction alone cannot see.
    from fractions import Fraction

    problem, y0 = collaboration(2), 0.6
    y1 = np.nextafter(y0 + 2 * HALF, 0.0)
    while Fraction(y1) - Fraction(y0) < 2 * Fraction(HALF):
        y1 = np.nextafter(y1, 1.0)
    touching = np.array([[0.2, y0], [0.2, y1]])
    assert is_valid(problem, touching, tol=0.0)
    assert not is_valid(problem, touching - [[0, 0], [0, y1 - np.nextafter(y1, 0.0)]], tol=0.0)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"half_sizes": np.zeros((2, 2))}, "half_sizes must be a finite array of shape"),
        ({"allowed_regions": ((0, 1),) * 2}, "one tuple per object"),
        ({"allowed_regions": ((0, 5),) * 3}, "index past"),
        ({"no_overlap": ((0, 0),)}, "two different objects"),
        ({"bounds": np.tile([1.0, -1.0], (3, 2, 1))}, "swap the bounds"),
    ],
)
def test_problem_validation_says_what_to_fix(change, match):
    names = ("object_names", "half_sizes", "regions", "allowed_regions", "no_overlap", "min_separation", "bounds")
    fields = {f: getattr(PAPER, f) for f in names}
    with pytest.raises(ValueError, match=match):
        RepairProblem(**(fields | change))


def test_region_validation():
    with pytest.raises(ValueError, match="swap the bounds"):
        Region(name="r", x=(1.0, 0.0), y=(0.0, 1.0))


def test_an_unproven_repair_at_the_time_limit_is_still_used():
    xy = np.tile([0.6, 0.05], (3, 1))  # the exact pile: the slowest case to prove
    result = repair(PAPER, xy, time_limit=0.05)
    assert result.status in ("repaired", "timeout")
    if result.status == "repaired":
        assert is_valid(PAPER, result.xy, tol=0.0)
        assert "not proven optimal" in result.message or "optimum" in result.message
