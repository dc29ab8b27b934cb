"""Times whole scenarios (repair -> simulate -> metrics) on one core and prints Markdown tables.

    python benchmarks/simulate.py                      # teleop (1,000) and collab (200)
    python benchmarks/simulate.py --spec specs/collab_wait.yaml --n 50

For each spec: uniformly random theta within the parameter bounds (seeded), evaluated one after
another in this process, after one warm-up scenario that is not counted (imports, first-call
caches). The first table is the throughput and the per-scenario latency; the second says where
the time goes, from a cProfile pass over the first ``--profile-n`` of the same theta (profiling
slows Python code more than C code, so read it as shares, not as times). Its rows are the
cumulative time of the calls that enter each part from outside it: ``repair`` (the spec's
constraint repair), ``world / MuJoCo`` (every ``hritest.sim`` call the task makes, with
``World(layout=...)`` construction also shown on its own), ``robot policy`` and ``human policy``
(the plugins' ``act`` and everything under it), ``metrics`` (``hritest.metrics`` and scoring);
``task loop`` is the rest: the task's own per-tick code, goal checks and plugin set-up.

Threads: BLAS and OpenMP pools are set to one thread before numpy loads, so a scenario never
uses more than the one core it is timed on; ``--cpu`` also pins the process to one CPU.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402 - after the thread settings, which must precede numpy
import cProfile  # noqa: E402
import pstats  # noqa: E402
import time  # noqa: E402
from collections import Counter  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from hritest.domain import Domain, compile_spec  # noqa: E402
from hritest.evaluate import evaluate, evaluate_with_rollout  # noqa: E402
from hritest.sim import World  # noqa: E402
from hritest.spec import load_spec  # noqa: E402

SPECS = Path(__file__).resolve().parent.parent / "specs"
DEFAULT_N = {"teleop": 1000, "collab": 200}
# Which functions enter each part, by (file suffix or folder ending in "/", function name or None for all).
PARTS = {
    "repair": (("hritest/repair/", None), ("hritest/constraints.py", None)),
    "world / MuJoCo": (("hritest/sim/world.py", None), ("hritest/sim/mjcf.py", None), ("hritest/sim/control.py", None)),
    "robot policy": (("plugins/robots.py", "act"),),
    "human policy": (("plugins/humans.py", "act"),),
    "metrics": (("hritest/metrics.py", None), ("hritest/evaluate.py", "_score")),
}
CONSTRUCTION = "of which `World(layout=...)`"


def thetas(domain: Domain, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(domain.space.lower, domain.space.upper, size=(n, len(domain.space.lower)))


def run(domain: Domain, points: np.ndarray) -> dict:
    """Evaluates every theta (seed = its index); wall and CPU times, simulated ticks, statuses."""
    evaluate(domain, points[0], seed=0)  # warm-up, not counted
    seconds, cpu, ticks, full, statuses = [], [], [], [], Counter()
    limit = domain.spec.task.time_limit
    for i, theta in enumerate(points):
        start, start_cpu = time.perf_counter(), time.process_time()
        evaluation, rollout = evaluate_with_rollout(domain, theta, seed=i)
        seconds.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
        statuses[evaluation.status] += 1
        if rollout is not None:
            ticks.append(len(rollout.time))
        # Episodes that ran to the time limit: the "full 10 s episode" (400 ticks in teleop).
        full.append(rollout is not None and rollout.time[-1] >= limit - 1e-9)
    return {
        "seconds": np.array(seconds),
        "cpu": np.array(cpu),
        "ticks": ticks,
        "full": np.array(full, dtype=bool),
        "statuses": statuses,
    }


def _is(func: tuple[str, int, str], suffix: str, name: str | None = None) -> bool:
    """Whether a cProfile function key is in a file ending with ``suffix``, or in a folder when it
    ends with ``/`` (and is ``name``)."""
    filename, _, function = func
    path = filename.replace(os.sep, "/")
    where = f"/{suffix}" in path if suffix.endswith("/") else path.endswith(suffix)
    return where and name in (None, function)


def _part_of(func: tuple[str, int, str]) -> str | None:
    return next((part for part, entries in PARTS.items() if any(_is(func, *entry) for entry in entries)), None)


def time_shares(domain: Domain, points: np.ndarray) -> dict[str, float]:
    """Seconds per part from one cProfile pass; see the module docstring for the parts."""
    profiler = cProfile.Profile()
    profiler.enable()
    for i, theta in enumerate(points):
        evaluate(domain, theta, seed=i)
    profiler.disable()
    stats = pstats.Stats(profiler).stats
    total = sum(ct for func, (_, _, _, ct, _) in stats.items() if _is(func, "hritest/evaluate.py", "evaluate"))
    shares = dict.fromkeys(PARTS, 0.0)
    for func, (_, _, _, _, callers) in stats.items():
        part = _part_of(func)
        if part is not None:
            # Only calls from outside the part: its internal calls are already inside these.
            shares[part] += sum(edge[3] for caller, edge in callers.items() if _part_of(caller) != part)
    shares["task loop"] = total - sum(shares.values())
    shares[CONSTRUCTION] = sum(
        ct for func, (_, _, _, ct, _) in stats.items() if _is(func, "hritest/sim/world.py", "__init__")
    )
    shares["total"] = total
    return shares


def world_construction_ms(domain: Domain, repeats: int = 20) -> float:
    """Milliseconds per ``World(layout=...)`` for the first scenario's scene (what every scenario
    would pay without :func:`hritest.sim.world.shared_world`)."""
    scenario = domain.space.bind(domain.repair(thetas(domain, 1, 0)[0]).theta)
    layout = domain.context(scenario).world
    start = time.perf_counter()
    for _ in range(repeats):
        World(layout=layout)
    return (time.perf_counter() - start) / repeats * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--spec",
        action="append",
        type=Path,
        help="spec file (repeatable); default: specs/teleop.yaml and specs/collab.yaml",
    )
    parser.add_argument("--n", type=int, help="scenarios per spec; default 1,000 teleop, 200 collab, 100 other")
    parser.add_argument("--profile-n", type=int, default=50, help="scenarios in the cProfile pass")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random theta")
    parser.add_argument("--cpu", type=int, help="pin this process to this CPU")
    args = parser.parse_args()
    if args.cpu is not None:
        os.sched_setaffinity(0, {args.cpu})
    paths = args.spec or [SPECS / "teleop.yaml", SPECS / "collab.yaml"]

    rows, shares, construction = [], {}, {}
    for path in paths:
        domain = compile_spec(load_spec(path))
        name = domain.spec.name
        points = thetas(domain, args.n or DEFAULT_N.get(name, 100), args.seed)
        result = run(domain, points)
        rows.append((name, result))
        shares[name] = time_shares(domain, points[: args.profile_n])
        construction[name] = world_construction_ms(domain)

    print(
        "| spec | scenarios | scenarios / s / core | median ms | p90 ms | max ms | median CPU ms "
        "| median ticks | full-length episodes: n, median ms | statuses |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, r in rows:
        ms = r["seconds"] * 1e3
        n = len(ms)
        statuses = ", ".join(f"{k} {v / n:.0%}" for k, v in r["statuses"].most_common())
        ticks = f"{np.median(r['ticks']):.0f}" if r["ticks"] else "-"
        full = ms[r["full"]]
        full_cell = f"{len(full)}, {np.median(full):.1f}" if len(full) else "0, -"
        print(
            f"| {name} | {n} | {n / r['seconds'].sum():.1f} | {np.median(ms):.1f} | "
            f"{np.percentile(ms, 90):.1f} | {ms.max():.1f} | {np.median(r['cpu']) * 1e3:.1f} | {ticks} "
            f"| {full_cell} | {statuses} |"
        )

    names = [name for name, _ in rows]
    print(
        f"\nWhere the time goes (cProfile over the first {args.profile_n} scenarios; share of "
        "`evaluate`'s cumulative time):\n"
    )
    print("| part | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for part in (*PARTS, "task loop", CONSTRUCTION):
        print(f"| {part} | " + " | ".join(f"{shares[n][part] / shares[n]['total']:.1%}" for n in names) + " |")
    print("| one `World(layout=...)`, unprofiled (ms) | " + " | ".join(f"{construction[n]:.2f}" for n in names) + " |")


if __name__ == "__main__":
    main()
