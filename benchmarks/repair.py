"""Times :func:`hritest.repair.repair` on the paper's collaboration instance.

Draws proposals the way the reference's random search does (each coordinate independently uniform
within ws1's or ws2's bounds, here extended by 0.05 m on each side so that some fall outside),
repairs each on one core and prints one Markdown table.

Run: ``python benchmarks/repair.py [--proposals 1000] [--seed 0]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hritest.repair import Region, RepairProblem, repair

HALF = 0.025
WS = {"ws1": ((0.6, 0.05), (0.08, 0.13)), "ws2": ((0.218, 0.626), (0.08, 0.13))}


def collaboration_problem() -> RepairProblem:
    """Three goals of half-size 0.025 m, each inside ws1 or ws2, pairwise not overlapping."""
    regions = tuple(
        Region(name=name, x=(c[0] - h[0], c[0] + h[0]), y=(c[1] - h[1], c[1] + h[1])) for name, (c, h) in WS.items()
    )
    n = 3
    return RepairProblem(
        object_names=tuple(f"goal{i}" for i in range(n)),
        half_sizes=np.full((n, 2), HALF),
        regions=regions,
        allowed_regions=((0, 1),) * n,
        no_overlap=((0, 1), (0, 2), (1, 2)),
        bounds=np.tile([-1 + HALF, 1 - HALF], (n, 2, 1)),
    )


def proposals(problem: RepairProblem, count: int, rng: np.random.Generator, pad: float = 0.05):
    """Each coordinate independently uniform in ws1's or ws2's range (chosen per coordinate)."""
    lo = np.array([[r.x[0], r.y[0]] for r in problem.regions]) - pad  # (regions, 2)
    hi = np.array([[r.x[1], r.y[1]] for r in problem.regions]) + pad
    pick = rng.integers(len(problem.regions), size=(count, problem.n, 2))
    axis = np.arange(2)
    return lo[pick, axis] + rng.random((count, problem.n, 2)) * (hi[pick, axis] - lo[pick, axis])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--proposals", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    problem = collaboration_problem()
    thetas = proposals(problem, args.proposals, np.random.default_rng(args.seed))
    repair(problem, thetas[0])  # warm-up: imports and first-call allocations
    times, solver, costs, statuses = [], [], [], []
    for xy in thetas:
        start = time.perf_counter()
        result = repair(problem, xy)
        times.append((time.perf_counter() - start) * 1e3)
        solver.append("CP-SAT" in result.message)
        costs.append(result.cost)
        statuses.append(result.status)
    times, solver = np.array(times), np.array(solver)

    def stats(t):
        return " | ".join(f"{v:.2f}" for v in np.percentile(t, [50, 90, 99, 100]))

    print(
        "| proposals | needing the solver | ms: median / p90 / p99 / max (all) "
        "| ms: median / p90 / p99 / max (solver only) | mean cost (m²) | statuses |"
    )
    print("|---|---|---|---|---|---|")
    counts = ", ".join(f"{s} {statuses.count(s)}" for s in sorted(set(statuses)))
    print(
        f"| {len(times)} | {solver.mean():.1%} | {stats(times).replace(' | ', ' / ')} "
        f"| {stats(times[solver]).replace(' | ', ' / ') if solver.any() else '-'} "
        f"| {np.mean(costs):.5f} | {counts} |"
    )


if __name__ == "__main__":
    main()
