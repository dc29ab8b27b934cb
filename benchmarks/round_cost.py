"""What one outer iteration's training costs as the data grows: the paper's schedule against the
incremental one, at each size of the training set.

    python benchmarks/round_cost.py specs/collab.yaml --samples 1000,10000 [--new 100] [--repeats 2]

The paper retrains both networks for ``epochs`` passes over all data every outer iteration, so a
round's cost grows with the data (and a run's with its square). The incremental schedule trains
the warm networks on the ``--new`` samples of the round and as many replayed old ones, so its cost
should not grow. This builds the spec's surrogate, fills the run-directory structures a search
uses (:class:`~hritest.search.training.TrainingData`, grids memory-mapped from an
``occupancy.f32`` file), and times, at each size, what a round costs: reading the dataset and
training (the incremental schedule the best of ``--repeats``, the paper's, minutes long at 10,000
samples, once). Random data: the cost of a round does not
depend on what the data says. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from hritest.domain import compile_spec
from hritest.search.training import GridRows, TrainingData
from hritest.spec import load_spec
from hritest.surrogate.model import Surrogate, pick_device


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("spec", type=Path)
    parser.add_argument("--samples", default="1000,10000")
    parser.add_argument("--new", type=int, default=100, help="samples new in the round")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    domain = compile_spec(load_spec(args.spec))
    settings = domain.spec.search.surrogate
    channels, outputs, dim = len(domain.grids), 1 + len(domain.measures), domain.space.dim
    rng = np.random.default_rng(0)

    def surrogate() -> Surrogate:
        return Surrogate(
            bounds=(domain.space.lower, domain.space.upper),
            channels=channels,
            outputs=outputs,
            epochs=settings.epochs,
            batch_size=settings.batch_size,
            learning_rate=settings.learning_rate,
            device=pick_device(args.device),
            seed=0,
        )

    print(
        f"{args.spec.name}: one outer iteration's training ({settings.epochs} epochs, batch {settings.batch_size}, "
        f"{channels} grid channels, {torch.get_num_threads()} threads), {args.new} new samples, "
        f"incremental best of {args.repeats}"
    )
    print()
    print("| samples | dataset s | paper round s | incremental round s | incremental / paper |")
    print("|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as folder:
        for n in (int(s) for s in args.samples.split(",")):
            data = TrainingData(dim=dim, outputs=outputs)
            for i in rng.permutation(n):  # finished out of order, as workers do
                data.append(
                    index=int(i),
                    line=len(data),
                    theta=rng.uniform(domain.space.lower, domain.space.upper),
                    targets=rng.random(outputs).tolist(),
                )
            path = Path(folder) / f"occupancy-{n}.f32"
            shape = (n, channels, 32, 32)
            rng.dirichlet(np.ones(1024), size=(n, max(channels, 1))).astype(np.float32)[:, :channels].tofile(path)
            start = time.perf_counter()
            theta, targets, lines = data.in_evaluation_order()
            grids = GridRows(np.memmap(path, dtype=np.float32, mode="r", shape=shape), lines) if channels else None
            reading = time.perf_counter() - start

            costs = {}
            for schedule in ("paper", "incremental"):
                best = np.inf
                for _ in range(args.repeats if schedule == "incremental" else 1):  # a paper round is long
                    model = surrogate()
                    model.fit(
                        theta[: args.new], None if grids is None else grids[np.arange(args.new)], targets[: args.new]
                    )  # warm: one earlier round, as in a run
                    old = n - args.new
                    rows = (
                        None
                        if schedule == "paper"
                        else np.concatenate(
                            [
                                np.sort(rng.choice(old, size=max(args.new, settings.batch_size), replace=False)),
                                np.arange(old, n),
                            ]
                        )
                    )
                    start = time.perf_counter()
                    model.fit(theta, grids, targets, rows=rows)
                    best = min(best, time.perf_counter() - start)
                costs[schedule] = best
            print(
                f"| {n:,} | {reading:.3f} | {costs['paper']:.2f} | {costs['incremental']:.2f} | "
                f"{costs['incremental'] / costs['paper']:.3f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
