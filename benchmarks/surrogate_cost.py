"""What the surrogate costs per outer iteration, the paper's schedule against the incremental one.

    python benchmarks/surrogate_cost.py specs/collab.yaml --evals 600 [--seed 0] [--workers 2]
        [--inner-iterations 300] [--stall 50] [--out DIR]

Runs SAS three ways on one spec and seed, one after the other on the same machine: the paper's
schedule (every outer iteration trains ``epochs`` passes over all data and runs every inner
iteration), ``training: incremental`` (new data plus as many replayed old samples), and
incremental with ``inner_stall`` (the inner loop stops once its archive stops growing). Prints a
Markdown table: the seconds of each outer iteration (from the run's progress.csv: the time from
one batch's end to the next, which is the training, the inner loop and the batch's simulations),
their sum (the initial random batch left out: it also pays the workers' start-up, which falls on
whichever run goes first), QD-score and the surrogate's held-out objective error, each also as a
ratio to the paper's schedule.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import shutil
from pathlib import Path

from hritest import search as qd

SCHEDULES = {
    "paper": {},
    "incremental": {"training": "incremental"},
    "incremental + stall": {"training": "incremental", "inner_stall": None},  # the stall comes from --stall
}


def spec_with(spec: Path, out: Path, settings: dict) -> Path:
    """``spec`` with ``settings`` merged into its search.surrogate, written into ``out``."""
    import yaml

    data = yaml.safe_load(spec.read_text())
    data.setdefault("search", {}).setdefault("surrogate", {}).update(settings)
    for key in ("task", "robot", "human"):  # plugin files are relative to the spec's folder
        part = data.get(key, {})
        for field in ("name", "policy"):
            value = part.get(field, "")
            if ".py:" in value:
                part[field] = str((spec.parent / value).resolve())
    world = data.get("world") or {}
    for part in (world, world.get("arm") or {}):
        if "model" in part:
            part["model"] = str((spec.parent / part["model"]).resolve())
    path = out / spec.name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def outer_seconds(run: Path) -> list[float]:
    with open(run / "progress.csv") as handle:
        rows = list(csv.DictReader(handle))
    times = [float(r["wall_time"]) for r in rows]
    return [b - a for a, b in itertools.pairwise(times)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("spec", type=Path)
    parser.add_argument("--evals", type=int, default=600)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--inner-iterations", type=int, default=300)
    parser.add_argument("--stall", type=int, default=50)
    parser.add_argument("--out", type=Path, default=Path("benchmark-runs/surrogate-cost"))
    args = parser.parse_args()
    rows = []
    for name, schedule in SCHEDULES.items():
        folder = args.out / name.replace(" ", "").replace("+", "-")
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        settings = {**schedule, **({"inner_stall": args.stall} if "inner_stall" in schedule else {})}
        spec = spec_with(args.spec, folder, settings)
        found = qd.start(
            spec_file=spec,
            out=folder / "run",
            algorithm="sas",
            budget=args.evals,
            seed=args.seed,
            backend=qd.Backend(workers=args.workers),
            surrogate=qd.SurrogateOptions(inner_iterations=args.inner_iterations, device="cpu"),
        )
        steps = outer_seconds(folder / "run")
        accuracy = json.loads((folder / "run" / "surrogate.json").read_text())
        rows.append(
            {
                "schedule": name,
                "outer": steps[1:],  # the first step is the initial random batch
                "wall": sum(steps[1:]),
                "qd": found.state.progress[-1].qd_score,
                "mae": accuracy["objective_mae"],
            }
        )
    base = rows[0]
    print(
        f"SAS on {args.spec}, {args.evals} evaluations, seed {args.seed}, {args.workers} workers, "
        f"{args.inner_iterations} inner iterations\n"
    )
    print("| schedule | seconds per outer iteration | sum s | x paper | QD-score | x paper | objective MAE |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        outer = ", ".join(f"{s:.1f}" for s in r["outer"])
        print(
            f"| {r['schedule']} | {outer} | {r['wall']:.1f} | {r['wall'] / base['wall']:.2f} | {r['qd']:,.0f} | "
            f"{r['qd'] / base['qd']:.2f} | {r['mae']:.4f} |"
        )


if __name__ == "__main__":
    main()
