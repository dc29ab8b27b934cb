"""What the search machinery itself costs, and how it scales from 1 to 2 workers.

    python benchmarks/search_overhead.py [--budget 3000] [--real-budget 300]

1. On the analytic toy domain (microseconds per evaluation), the wall time of a CMA-MAE run per
   evaluation, minus the time spent inside evaluations: ask/tell, process pool, run-directory
   writes, checkpoints. Target: <= 1 ms per evaluation.
2. On a real spec (teleoperation, Random search), evaluations per second with 1 and 2 workers.
   Target: >= 1.8x.
Prints Markdown tables.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from hritest import search as qd

ROOT = Path(__file__).resolve().parents[1]


def timed_run(spec: Path, *, algorithm: str, budget: int, workers: int) -> tuple[float, float]:
    """(wall seconds, seconds spent inside evaluations) of one search."""
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        qd.start(
            spec_file=spec,
            out=Path(folder) / "run",
            algorithm=algorithm,
            budget=budget,
            seed=0,
            backend=qd.Backend(workers=workers, timeout=60),
        )
        wall = time.perf_counter() - start
        lines = (Path(folder) / "run" / "evaluations.jsonl").read_text().splitlines()
        inside = sum(json.loads(line)["seconds"] for line in lines)
    return wall, inside


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget", type=int, default=3000)
    parser.add_argument("--real-budget", type=int, default=300)
    parser.add_argument("--real-spec", type=Path, default=ROOT / "specs" / "teleop.yaml")
    args = parser.parse_args()

    toy = ROOT / "tests" / "fixtures" / "toy.yaml"
    timed_run(toy, algorithm="cma_mae", budget=300, workers=1)  # warm caches (numba JIT, imports)
    print(
        "| machinery (toy domain, CMA-MAE, 1 worker) | evaluations | wall s | in evaluations s "
        "| overhead ms / evaluation |"
    )
    print("|---|---|---|---|---|")
    wall, inside = timed_run(toy, algorithm="cma_mae", budget=args.budget, workers=1)
    print(f"| whole run | {args.budget} | {wall:.2f} | {inside:.2f} | {(wall - inside) / args.budget * 1e3:.3f} |")
    print()
    print(f"| scaling ({args.real_spec.name}, Random) | workers | evaluations | wall s | evaluations / s | speed-up |")
    print("|---|---|---|---|---|---|")
    base = None
    for workers in (1, 2):
        wall, _ = timed_run(args.real_spec, algorithm="random", budget=args.real_budget, workers=workers)
        rate = args.real_budget / wall
        base = base or rate
        print(f"| | {workers} | {args.real_budget} | {wall:.2f} | {rate:.1f} | {rate / base:.2f}x |")


if __name__ == "__main__":
    main()
