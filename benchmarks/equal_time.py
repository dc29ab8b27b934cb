"""Every algorithm for the same wall time: QD-score at each mark, over the best model-free one.

    python benchmarks/equal_time.py specs/collab.yaml --minutes 5,15 --seeds 3 \\
        [--algorithms random,map_elites,cma_mae:1,sas,dsas,auto] [--inner-iterations 300] \\
        [--training incremental] [--inner-stall 50] [--time-share 0.33] [--selection gain] [--workers 2] \\
        [--device cpu] [--out DIR]

A user has a CI budget or an afternoon, not an evaluation count, so this is the comparison that
decides what they should run. Each run is one ``hritest search --time-limit`` of the longest mark,
one after another (never side by side: they would share the cores), and its ``progress.csv``
gives the QD-score at each mark: that of the last batch told by then, in search wall time (the
time spent proposing and simulating, without the process's start-up). Prints a Markdown table with
each algorithm's QD-score at every mark (mean ± standard error over seeds), its ratio to the best
model-free algorithm's mean at that mark, its evaluations, and the share of its time spent
proposing (for SAS and DSAS: training the surrogate and its inner loop); writes it into ``--out``.
``name:N`` in ``--algorithms`` runs that algorithm for seeds 0 to N-1 only (one far behind the
others needs no three seeds to say so).

A stopped comparison continues: the same command with the same ``--out`` reuses every run that
reached the longest mark and resumes a shorter one for the time it lacks. ``--out`` remembers the
commit its runs were made at, and a later commit refuses to reuse them (``--reuse-stale`` to do it
anyway, e.g. to add seeds of an algorithm whose code did not change).
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

from compare import add_surrogate_arguments, mean_sem, surrogate_options

from hritest import search as qd
from hritest.search.algorithms import MODEL_FREE

REACHED = "equal_time_reached.txt"  # in a run: the seconds this script last brought it to


def progress(run: Path) -> list[dict[str, float]]:
    try:
        with open(run / "progress.csv", newline="") as handle:
            return [{k: float(v) for k, v in row.items() if k != "proposer"} for row in csv.DictReader(handle)]
    except OSError:
        return []


def at(rows: list[dict[str, float]], seconds: float) -> dict[str, float]:
    """The last row told within ``seconds`` of search wall time (an empty archive before the first)."""
    told = [r for r in rows if r["wall_time"] <= seconds]
    return told[-1] if told else {"qd_score": 0.0, "evaluations": 0, "wall_time": 0.0}


def run_for(run: Path, *, spec: Path, algorithm: str, seed: int, seconds: float, args: argparse.Namespace) -> None:
    """Brings ``run`` to ``seconds`` of search wall time: reused, resumed, or started anew."""
    rows = progress(run)
    done = rows[-1]["wall_time"] if rows else 0.0
    try:
        meta = json.loads((run / "run.json").read_text())
    except (OSError, ValueError):
        meta = {}
    same = meta.get("algorithm") == algorithm and meta.get("seed") == seed
    # A run stops up to a batch short of its limit: the marker says it was brought to ``seconds``.
    reached = float((run / REACHED).read_text()) if (run / REACHED).is_file() else 0.0
    if same and max(done, reached) >= seconds - 1:
        print(f"{algorithm} seed {seed}: {done:.0f} s earlier in {run}, reused", flush=True)
        return
    backend = qd.Backend(workers=args.workers)
    if same and (run / "checkpoint.pkl").is_file():
        print(f"{algorithm} seed {seed}: {done:.0f} s earlier in {run}, resumed", flush=True)
        qd.resume(run_path=run, time_limit=seconds - done, backend=backend)
        (run / REACHED).write_text(f"{seconds}\n")
        return
    if run.exists():
        shutil.rmtree(run)
    qd.start(
        spec_file=spec,
        out=run,
        algorithm=algorithm,
        time_limit=seconds,
        seed=seed,
        backend=backend,
        surrogate=surrogate_options(args),
    )
    (run / REACHED).write_text(f"{seconds}\n")


def commit() -> str:
    """The checkout's commit, marked ``-dirty`` with uncommitted changes (``unknown`` outside git)."""
    try:
        return subprocess.run(
            ["git", "describe", "--always", "--dirty"], capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def check_same_code(out: Path, *, reuse_stale: bool) -> None:
    """Refuses to mix runs made by different code in one table, unless told to."""
    mark, now = out / "commit.txt", commit()
    before = mark.read_text().strip() if mark.is_file() else None
    if before not in (None, now) and not reuse_stale:
        sys.exit(
            f"{out} holds runs made at commit {before}, and this checkout is {now}: a table mixing them "
            "compares different code. Use a new --out, or pass --reuse-stale if the algorithms' code "
            "did not change."
        )
    out.mkdir(parents=True, exist_ok=True)
    if before is None:
        mark.write_text(now + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("spec", type=Path)
    parser.add_argument("--algorithms", default="random,map_elites,cma_mae,sas,dsas,auto")
    parser.add_argument("--minutes", default="5,15", help="the marks, comma-separated; runs last the longest")
    parser.add_argument("--seeds", type=int, default=3)
    add_surrogate_arguments(parser, inner_iterations=300, device="cpu")  # auto sizes its own inner loop
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--reuse-stale", action="store_true", help="reuse runs made at another commit")
    args = parser.parse_args()
    seeds = {}
    for item in filter(None, (a.strip() for a in args.algorithms.split(","))):
        name, _, count = item.partition(":")
        seeds[name] = int(count) if count else args.seeds
    algorithms = list(seeds)
    marks = sorted(float(m) for m in args.minutes.split(","))
    out = args.out or Path("benchmark-runs") / f"equal-time-{args.spec.stem}-{time.strftime('%Y%m%d-%H%M%S')}"
    check_same_code(out, reuse_stale=args.reuse_stale)

    rows: dict[str, list[list[dict[str, float]]]] = {a: [] for a in algorithms}
    for seed in range(max(seeds.values())):
        for algorithm in (a for a in algorithms if seed < seeds[a]):
            run = out / f"{algorithm}-s{seed}"
            run_for(run, spec=args.spec, algorithm=algorithm, seed=seed, seconds=60 * marks[-1], args=args)
            rows[algorithm].append(progress(run))
            last = rows[algorithm][-1][-1]
            print(f"{algorithm} seed {seed}: QD-score {last['qd_score']:,.1f} at {last['wall_time']:.0f} s", flush=True)

    def mean_at(algorithm: str, minutes: float) -> float:
        return statistics.fmean(at(r, 60 * minutes)["qd_score"] for r in rows[algorithm])

    best = {m: max((mean_at(a, m) for a in algorithms if a in MODEL_FREE), default=None) for m in marks}
    header = ["algorithm", "seeds"]
    for m in marks:
        header += [f"QD-score at {m:g} min", "/ best model-free"]
    header += [f"evaluations at {marks[-1]:g} min", "proposing share"]
    lines = [
        f"{args.spec.name}: equal wall time, {args.workers} workers, SAS/DSAS inner "
        f"iterations {args.inner_iterations:,}, training {args.training or 'as the spec'}, inner stall "
        f"{args.inner_stall or 'as the spec'}, time share {args.time_share or 'as the spec'}, "
        f"selection {args.selection or 'as the spec'}",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
    ]
    for algorithm in algorithms:
        cells = [algorithm, str(len(rows[algorithm]))]
        for m in marks:
            scores = [at(r, 60 * m)["qd_score"] for r in rows[algorithm]]
            ratio = f"{statistics.fmean(scores) / best[m]:.2f}" if best[m] else "n/a"
            cells += [mean_sem(scores), ratio]
        ends = [at(r, 60 * marks[-1]) for r in rows[algorithm]]
        proposing = sum(x.get("propose_seconds", 0.0) for r in rows[algorithm] for x in r)
        wall = sum(r[-1]["wall_time"] for r in rows[algorithm] if r)
        cells += [f"{statistics.fmean(e['evaluations'] for e in ends):,.0f}", f"{proposing / max(wall, 1e-9):.0%}"]
        lines.append("| " + " | ".join(cells) + " |")
    table = "\n".join(lines)
    print(table)
    (out / "table.md").write_text(table + "\n")


if __name__ == "__main__":
    main()
