"""Wall time of one outer iteration's inner loop of SAS and DSAS (iterations x 8 emitters x 37).

    python benchmarks/inner_loop.py [--spec specs/teleop.yaml] [--iterations 10000] [--device cpu|cuda|auto]

The surrogate is trained briefly on random data first (its weights do not change the cost).
Prints a Markdown table: total seconds, ms per iteration, and the split between surrogate
forward passes, Jacobians (DSAS) and pyribs' own ask/tell. The paper's reference spent about
190-310 s of surrogate overhead per outer iteration on a GPU; targets: <= 120 s per inner loop
on 2 CPU cores, <= 15 s on an H100.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from hritest.domain import compile_spec
from hritest.search.inner import SurrogateObjective, exploit
from hritest.spec import load_spec
from hritest.surrogate.model import Surrogate, pick_device

ROOT = Path(__file__).resolve().parents[1]


class Timed(SurrogateObjective):
    """The inner loop's objective, with the time spent in it added up."""

    forward = jacobian = 0.0

    def __call__(self, solutions):
        start = time.perf_counter()
        result = super().__call__(solutions)
        _sync(self.device)
        Timed.forward += time.perf_counter() - start
        return result

    def with_jacobian(self, solutions):
        start = time.perf_counter()
        result = super().with_jacobian(solutions)
        _sync(self.device)
        Timed.jacobian += time.perf_counter() - start
        return result


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", type=Path, default=ROOT / "specs" / "teleop.yaml")
    parser.add_argument("--iterations", type=int, default=10_000)
    parser.add_argument("--device", default="auto")
    args = parser.parse_args()

    domain = compile_spec(load_spec(args.spec))
    device = pick_device(args.device)
    rng = np.random.default_rng(0)
    n, channels = domain.space.dim, len(domain.grids)
    surrogate = Surrogate(
        bounds=(domain.space.lower, domain.space.upper),
        channels=channels,
        outputs=1 + len(domain.measures),
        epochs=2,
        batch_size=64,
        learning_rate=1e-4,
        device=device,
        seed=0,
    )
    theta = rng.uniform(domain.space.lower, domain.space.upper, size=(256, n)).astype(np.float32)
    grids = rng.dirichlet(np.ones(1024), size=(256, channels)).reshape(256, channels, 32, 32).astype(np.float32)
    surrogate.fit(theta, grids, rng.random((256, 1 + len(domain.measures))).astype(np.float32))
    exploit(domain, Timed(domain, surrogate), gradients=True, iterations=3, seed=0)  # JIT and warm-up

    print(
        f"| {args.spec.name} on {device} ({torch.get_num_threads()} threads) | iterations | total s | ms / iteration "
        "| surrogate forward s | Jacobians s | pyribs and the rest s |"
    )
    print("|---|---|---|---|---|---|---|")
    for name, gradients in (("SAS", False), ("DSAS", True)):
        Timed.forward = Timed.jacobian = 0.0
        start = time.perf_counter()
        exploit(domain, Timed(domain, surrogate), gradients=gradients, iterations=args.iterations, seed=1)
        total = time.perf_counter() - start
        rest = total - Timed.forward - Timed.jacobian
        print(
            f"| {name} | {args.iterations} | {total:.1f} | {total / args.iterations * 1e3:.2f} | "
            f"{Timed.forward:.1f} | {Timed.jacobian:.1f} | {rest:.1f} |"
        )


if __name__ == "__main__":
    main()
