"""How much shrinking simplifies a run's failures.

    python benchmarks/shrink.py RUN [--failures 10] [--budget 100]

Shrinks the run's first failures (failures.yaml's order, worst first) and prints a Markdown table:
each failure's clause, the parameters away from nominal before and after, the simulations spent,
and whether the shrunk scenario still fails with the same clause (it must).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import yaml

from hritest.evaluate import evaluate
from hritest.replay import run_domain
from hritest.rundir import RunDirectory
from hritest.shrink import shrink_failure


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--failures", type=int, default=10)
    parser.add_argument("--budget", type=int, default=100)
    args = parser.parse_args()
    failures = yaml.safe_load((args.run / "failures.yaml").read_text())["failures"][: args.failures]
    domain = run_domain(RunDirectory.open(args.run))
    print(f"{args.run}: {len(failures)} failures, budget {args.budget} simulations each\n")
    print("| failure | clause | away from nominal: before | after | simulations | still fails that way |")
    print("|---|---|---|---|---|---|")
    fewer = 0
    for failure in failures:
        result, _ = shrink_failure(args.run, failure["id"], budget=args.budget)
        before, after = len(result.off_nominal(result.original)), len(result.off_nominal(result.theta))
        again = evaluate(domain, result.theta, seed=failure["seed"])
        holds = again.ok and any(c.text == result.clause for c in again.fired)
        fewer += after < before
        print(f"| {failure['id']} | `{result.clause}` | {before} | {after} | {result.evaluations} | {holds} |")
    print(f"\nfewer parameters away from nominal on {fewer} of {len(failures)} failures")


if __name__ == "__main__":
    main()
