"""The paper's experiment: every algorithm on one spec, several seeds, QD-score at the end.

    python benchmarks/compare.py specs/teleop.yaml --algorithms dsas,sas,cma_mae,map_elites,random \\
        --evals 2000 --seeds 3 [--inner-iterations 1000] [--training incremental] [--inner-stall 50] \\
        [--workers 2] [--device auto] [--out DIR]

Prints a Markdown table (final QD-score raw and normalised, mean +- standard error over seeds,
coverage, best objective, search wall time, evaluations per second, and each algorithm's QD-score
over Random's), and writes it with every run and a comparison report (curves and heatmaps side by
side, one run per algorithm: its first seed) into ``--out``. Runs go seed by seed; the same
command with the same ``--out`` reuses the runs that finished and resumes a stopped one from its
last checkpoint (when its settings and spec are the same), so a stopped comparison continues:
this is how a run longer than one sitting (the paper's protocol on a CPU) gets done.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import shutil
import statistics
import sys
import time
from pathlib import Path

from hritest import search as qd
from hritest.report import compare_runs
from hritest.rundir import digest
from hritest.search.loop import SURROGATE
from hritest.spec import load_spec


def final_row(run: Path) -> dict[str, float]:
    with open(run / "progress.csv") as handle:
        rows = list(csv.DictReader(handle))
    return {k: float(v) for k, v in rows[-1].items() if k != "proposer"}


def same_run(run: Path, *, algorithm: str, evals: int, seed: int, surrogate: dict, spec: Path) -> bool:
    """Whether ``run`` is a run of these settings (``surrogate``: SAS's and DSAS's ``run.json``
    entries) and of this spec: one a comparison run again may reuse or continue."""
    try:
        meta = json.loads((run / "run.json").read_text())
    except (OSError, ValueError):
        return False
    wanted = {"algorithm": algorithm, "budget": evals, "seed": seed, "spec_digest": digest(spec)}
    if algorithm in SURROGATE:
        wanted |= surrogate
    before = {
        "training": "paper",
        "inner_stall": None,
        "pipeline": False,
        "time_share": 1.0,
        "selection": "random",
        "screen": False,
    }
    # (runs made before those settings existed)
    meta = before | meta
    return all(meta.get(k) == v for k, v in wanted.items())


def finished(run: Path, evaluations: int) -> bool:
    """Whether ``run`` got to the end of its budget."""
    try:
        return final_row(run)["evaluations"] == evaluations
    except (OSError, KeyError, IndexError, ValueError):
        return False


def mean_sem(values: list[float]) -> str:
    mean = statistics.fmean(values)
    sem = statistics.stdev(values) / math.sqrt(len(values)) if len(values) > 1 else 0.0
    return f"{mean:,.1f} ± {sem:,.1f}" if abs(mean) >= 10 else f"{mean:.4f} ± {sem:.4f}"


def add_surrogate_arguments(parser: argparse.ArgumentParser, *, inner_iterations: int | None, device: str) -> None:
    """The SAS and DSAS settings a benchmark overrides (default: the spec's), for :func:`surrogate_options`."""
    parser.add_argument("--inner-iterations", type=int, default=inner_iterations)
    parser.add_argument("--training", choices=["paper", "incremental"], default=None, help="default: the spec's")
    parser.add_argument("--inner-stall", type=int, default=None, help="SAS and DSAS; default: the spec's")
    parser.add_argument(
        "--pipeline", action=argparse.BooleanOptionalAction, default=None, help="SAS and DSAS; default: the spec's"
    )
    parser.add_argument(
        "--time-share",
        type=float,
        default=None,
        help="SAS and DSAS; default: the spec's (1: the surrogate is never cut)",
    )
    parser.add_argument(
        "--selection", choices=["gain", "random"], default=None, help="SAS and DSAS; default: the spec's"
    )
    parser.add_argument(
        "--screen", action=argparse.BooleanOptionalAction, default=None, help="SAS and DSAS; default: the spec's"
    )
    parser.add_argument("--device", default=device)


def surrogate_options(args: argparse.Namespace) -> qd.SurrogateOptions:
    return qd.SurrogateOptions(
        inner_iterations=args.inner_iterations,
        device=args.device,
        training=args.training,
        inner_stall=args.inner_stall,
        pipeline=args.pipeline,
        time_share=args.time_share,
        selection=args.selection,
        screen=args.screen,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("spec", type=Path)
    parser.add_argument("--algorithms", default="dsas,sas,cma_mae,map_elites,random")
    parser.add_argument("--evals", type=int, default=2000)
    parser.add_argument("--seeds", type=int, default=3)
    add_surrogate_arguments(parser, inner_iterations=None, device="auto")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    algorithms = [a.strip() for a in args.algorithms.split(",") if a.strip()]
    settings = surrogate_options(args).applied_to(load_spec(args.spec).search.surrogate)
    surrogate = settings.model_dump(include=set(qd.SurrogateOptions.SETTINGS))
    out = args.out or Path("benchmark-runs") / f"{args.spec.stem}-{time.strftime('%Y%m%d-%H%M%S')}"

    results: dict[str, list[dict[str, float]]] = {a: [] for a in algorithms}
    for seed in range(args.seeds):  # seed by seed, so that a stopped comparison has every algorithm
        for algorithm in algorithms:
            run = out / f"{algorithm}-s{seed}"
            same = same_run(run, algorithm=algorithm, evals=args.evals, seed=seed, surrogate=surrogate, spec=args.spec)
            if same and finished(run, args.evals):
                print(f"{algorithm} seed {seed}: finished earlier in {run}, reused", flush=True)
            elif same and (run / "checkpoint.pkl").is_file():
                print(f"{algorithm} seed {seed}: stopped earlier in {run}, resumed", flush=True)
                qd.resume(run_path=run, backend=qd.Backend(workers=args.workers))
            else:
                if run.exists() and not same:
                    sys.exit(
                        f"{run} is a run of other settings or of another version of {args.spec}; "
                        "use another --out, or move the run away"
                    )
                if run.exists():  # it never checkpointed: nothing to continue
                    shutil.rmtree(run)
                qd.start(
                    spec_file=args.spec,
                    out=run,
                    algorithm=algorithm,
                    budget=args.evals,
                    seed=seed,
                    backend=qd.Backend(workers=args.workers),
                    surrogate=surrogate_options(args),
                )
            row = final_row(run)
            row["total_seconds"] = row["wall_time"]
            results[algorithm].append(row)
            print(
                f"{algorithm} seed {seed}: QD-score {row['qd_score']:,.1f} in {row['total_seconds']:.0f} s", flush=True
            )

    random_qd = statistics.fmean(r["qd_score"] for r in results["random"]) if "random" in results else None
    lines = [
        f"{args.spec.name}: {args.evals} evaluations, {args.seeds} seeds, inner iterations "
        f"{settings.inner_iterations:,} (SAS, DSAS), training {settings.training}, inner stall "
        f"{settings.inner_stall or 'none'}, pipeline {settings.pipeline}, time share {settings.time_share}, "
        f"selection {settings.selection}, screen {settings.screen}, {args.workers} workers",
        "",
        "| algorithm | QD-score | normalised QD-score | coverage | best | wall s | evaluations / s "
        "| QD-score / Random |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for algorithm, rows in results.items():
        qd_scores = [r["qd_score"] for r in rows]
        seconds = statistics.fmean(r["total_seconds"] for r in rows)
        ratio = f"{statistics.fmean(qd_scores) / random_qd:.2f}" if random_qd else "n/a"
        lines.append(
            f"| {algorithm} | {mean_sem(qd_scores)} | {mean_sem([r['normalized_qd_score'] for r in rows])} | "
            f"{mean_sem([r['coverage'] for r in rows])} | {statistics.fmean(r['best'] for r in rows):.3g} | "
            f"{seconds:,.0f} | {args.evals / seconds:.1f} | {ratio} |"
        )
    table = "\n".join(lines)
    print(table)
    (out / "table.md").write_text(table + "\n")
    page = compare_runs([out / f"{a}-s0" for a in results], out / "report")
    print(f"comparison report: {page}")


if __name__ == "__main__":
    main()
