"""The inner loop of SAS and DSAS: quality-diversity search on the surrogate, then selection.

Each outer iteration builds a fresh archive and fresh emitters at x0 and runs ``iterations``
rounds of CMA-MAE (SAS) or CMA-MAEGA (DSAS) where every batch, from all emitters at once, is
scored by one forward pass of the surrogate (and, for DSAS, the objective and measure gradients
of the emitters' solution points by one backward pass over stacked copies of them). The elites
are then downsampled, one random elite per block of cells, to choose what the real simulator
evaluates.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable

import numpy as np
import torch
from ribs.archives import ArchiveBase, CVTArchive, GridArchive
from ribs.emitters import EvolutionStrategyEmitter, GradientArborescenceEmitter
from ribs.schedulers import Scheduler

from hritest.domain import Domain
from hritest.search import algorithms, archives
from hritest.surrogate.inference import keep_freed_memory
from hritest.surrogate.model import Surrogate
from hritest.surrogate.penalty import Penalty


class SurrogateObjective:
    """Scores solutions on the surrogate: objective = prediction - penalty, measures = prediction
    plus, where the spec has several regions, each object's nearest region (no gradient)."""

    def __init__(self, domain: Domain, surrogate: Surrogate) -> None:
        self.device, self.clip = surrogate.device, surrogate.clip
        self.network = surrogate.refolded()  # the surrogate as trained now; rebuilt each outer iteration
        self.penalty = Penalty(domain.repair.penalty_terms(), surrogate.device)
        self.region_axes = len(archives.workspace_objects(domain)) > 0
        self.calls = 0  # batches scored: the inner loop's iterations

    def _outputs(self, x: torch.Tensor) -> torch.Tensor:
        predicted = self.network(self.clip(x))
        return torch.cat([predicted[:, :1] - self.penalty(x)[:, None], predicted[:, 1:]], dim=1)

    def __call__(self, solutions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self.calls += 1
        with torch.inference_mode():
            x = torch.as_tensor(solutions, dtype=torch.float32, device=self.device)
            out = self._outputs(x)
            measures = self._with_regions(x, out[:, 1:])
            return out[:, 0].double().cpu().numpy(), measures.double().cpu().numpy()

    def with_jacobian(self, solutions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Objective, measures and ``(batch, 1 + measures, dim)`` Jacobian (region rows are zero).

        In eval mode rows do not interact, so one forward pass over ``outputs`` stacked copies of
        the batch and one backward pass of the sum of copy ``j``'s output ``j`` give every row.
        """
        x = torch.as_tensor(solutions, dtype=torch.float32, device=self.device)
        n, outputs = len(x), self.network.outputs
        copies = x.repeat(outputs, 1).requires_grad_(True)
        stacked = self._outputs(copies).view(outputs, n, outputs)
        picked = stacked.diagonal(dim1=0, dim2=2)  # (n, outputs): copy j's output j
        (gradient,) = torch.autograd.grad(picked.sum(), copies)
        jacobian = gradient.view(outputs, n, -1).transpose(0, 1)
        out = stacked[0].detach()
        with torch.no_grad():
            measures = self._with_regions(x, out[:, 1:])
            if self.region_axes:
                zeros = jacobian.new_zeros((len(x), measures.shape[1] - (out.shape[1] - 1), x.shape[1]))
                jacobian = torch.cat([jacobian, zeros], dim=1)
        return (out[:, 0].double().cpu().numpy(), measures.double().cpu().numpy(), jacobian.double().cpu().numpy())

    def _with_regions(self, x: torch.Tensor, measures: torch.Tensor) -> torch.Tensor:
        return torch.cat([measures, self.penalty.regions(x)], dim=1) if self.region_axes else measures


STALL_GROWTH = 0.01  # the relative QD-score growth an inner loop must keep up to go on, with inner_stall


def exploit(
    domain: Domain,
    objective: SurrogateObjective,
    *,
    gradients: bool,
    iterations: int,
    seed: int,
    stall: int | None = None,
    deadline: float | None = None,
) -> ArchiveBase:
    """Runs the inner loop from scratch and returns its archive of surrogate elites.

    With ``stall``, it stops early once the archive's QD-score has not grown by
    :data:`STALL_GROWTH` in ``stall`` iterations: an inner loop that has found what the
    surrogate knows only costs time. With ``deadline`` (a ``time.monotonic()`` value), it stops
    then, after at least one iteration.
    """
    keep_freed_memory()
    settings = domain.spec.search.emitter
    archive = archives.search_archive(domain, seed=seed)
    seeds = np.random.SeedSequence(seed).generate_state(settings.emitters)
    start = algorithms.x0(domain)
    if gradients:
        emitters = [
            GradientArborescenceEmitter(
                archive,
                x0=start,
                sigma0=algorithms.sigma0(domain),
                lr=settings.gradient_lr,
                ranker="imp",
                grad_opt="gradient_ascent",
                restart_rule="basic",
                normalize_grad=True,
                batch_size=settings.batch_size,
                seed=int(s),
            )
            for s in seeds
        ]
    else:
        emitters = [
            EvolutionStrategyEmitter(
                archive,
                x0=start,
                sigma0=algorithms.sigma0(domain),
                **algorithms.CMA_MAE_RULES,
                batch_size=settings.batch_size,
                seed=int(s),
            )
            for s in seeds
        ]
    scheduler = Scheduler(archive, emitters)
    with warnings.catch_warnings():
        # From x0 (zeros, far outside every region in the collaboration specs) the first batches can
        # all score below threshold_min; ribs then warns of an empty archive, which the emitters soon
        # leave. Not the user's concern.
        warnings.filterwarnings("ignore", message="`archive` was empty before adding solutions")
        best, since = -np.inf, 0
        for _ in range(iterations):
            if gradients:
                points = scheduler.ask_dqd()
                scheduler.tell_dqd(*objective.with_jacobian(points))
            solutions = scheduler.ask()
            scheduler.tell(*objective(solutions))
            if deadline is not None and time.monotonic() >= deadline:
                break
            if stall is not None:
                score = archive.stats.qd_score
                if score > best + STALL_GROWTH * abs(best) or not np.isfinite(best):
                    best, since = score, 0
                else:
                    since += 1
                    if since >= stall:
                        break
    return archive


def downsample(
    domain: Domain,
    archive: ArchiveBase,
    *,
    rng: np.random.Generator,
    incumbents: Callable[[np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """One elite per block of the selection archive, in a random order.

    For a grid, the selection grid has the spec's ``downsample_cells`` per measure (default: the
    archive's own cells, i.e. every elite) and a single cell along each region axis, as in the
    reference. For a cvt archive, the blocks are the cells of a coarser tessellation of the spec's
    measures, ``downsample_cells`` of them (default: every elite is its own block).

    Without ``incumbents``, a uniformly random elite of each block (the reference's). With it (the
    result archive's objective in the cells of given measures), the elite predicted to gain the
    QD-score the most: its predicted objective over the incumbent of the cell it predicts. A block
    spans several cells, some already well filled; a random pick spends simulations there as often
    as on the cells where a scenario would add (`docs/decisions.md`).
    """
    data = archive.data(["solution", "objective", "measures"])
    if len(data["solution"]) == 0:
        return np.zeros((0, domain.space.dim))
    cells = domain.spec.search.surrogate.downsample_cells
    measures = data["measures"][:, : len(domain.measures)]
    if domain.spec.archive.type == "cvt":
        block = (
            np.arange(len(measures))
            if cells is None
            else CVTArchive(
                solution_dim=1, centroids=archives.centroids(domain, cells=cells[0]), ranges=domain.archive_ranges
            ).index_of(measures)
        )
    else:
        grid = GridArchive(solution_dim=1, dims=cells or list(domain.archive_dims), ranges=domain.archive_ranges)
        block = grid.index_of(measures)
    if incumbents is None:
        order = rng.permutation(len(block))
    else:  # the search archive's objective is normalised by the objective's span (the surrogate's targets)
        lo, hi = domain.spec.objective.range
        gain = data["objective"] * (hi - lo) - incumbents(measures)
        order = np.lexsort((rng.random(len(block)), -gain))  # largest gain first, ties at random
    _, first = np.unique(block[order], return_index=True)  # the first of each block in that order
    chosen = order[first]
    return data["solution"][rng.permutation(chosen)]
