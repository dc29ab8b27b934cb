"""The model-free algorithms as pyribs schedulers: Random, MAP-Elites and CMA-MAE.

Settings come from the spec (defaults: the paper's). Every emitter gets its own seed drawn
from the run's seed, so a run is reproducible from the spec and seed alone.
"""

from __future__ import annotations

import functools

import numpy as np
from ribs.archives import GridArchive
from ribs.emitters import EmitterBase, EvolutionStrategyEmitter, GaussianEmitter
from ribs.schedulers import Scheduler

from hritest.domain import Domain

MODEL_FREE = ("random", "map_elites", "cma_mae")
CMA_MAE_RULES = {"ranker": "imp", "selection_rule": "mu", "restart_rule": "basic"}  # the paper's CMA-MAE emitters


class UniformEmitter(EmitterBase):
    """Uniform samples within the parameter bounds: the paper's Random Search as an emitter.

    pyribs has no such emitter; this keeps Random on the same ask/tell loop as the others.
    """

    def __init__(self, archive, *, lower: np.ndarray, upper: np.ndarray, batch_size: int, seed: int) -> None:  # noqa: ANN001 - a ribs archive
        super().__init__(archive, solution_dim=archive.solution_dim, bounds=None, lower_bounds=None, upper_bounds=None)
        self._lower, self._upper = np.asarray(lower), np.asarray(upper)
        self._batch_size = batch_size
        self._rng = np.random.default_rng(seed)

    @property
    def batch_size(self) -> int:
        return self._batch_size

    def ask(self) -> np.ndarray:
        return self._rng.uniform(self._lower, self._upper, size=(self._batch_size, len(self._lower)))


def x0(domain: Domain) -> np.ndarray:
    """The emitters' start: the spec's ``x0``, else the centre of the bounds (the paper's ``x0 = 0``
    lay outside them, so repair piled the first batches on their edges)."""
    given = domain.spec.search.emitter.x0
    return np.array(given, dtype=float) if given is not None else (domain.space.lower + domain.space.upper) / 2


def sigma0(domain: Domain) -> float:
    """The emitters' step: the spec's ``sigma0``, else a sixth of the bounds' typical width (their
    geometric mean), so that a first batch spreads over the space whatever its units."""
    given = domain.spec.search.emitter.sigma0
    if given is not None:
        return given
    widths = domain.space.upper - domain.space.lower
    return float(np.exp(np.mean(np.log(widths[widths > 0])))) / 6 if np.any(widths > 0) else 1.0


def scheduler(domain: Domain, algorithm: str, archive, *, seed: int, starts: np.ndarray | None = None) -> Scheduler:  # noqa: ANN001 - a ribs archive
    """The pyribs scheduler of a model-free ``algorithm`` over the search ``archive``; CMA-MAE's
    emitters start at :func:`x0`, or each at its row of ``starts``."""
    search = domain.spec.search
    seeds = np.random.SeedSequence(seed).generate_state(search.emitter.emitters + 1)
    if algorithm == "random":
        emitters = [
            UniformEmitter(
                archive,
                lower=domain.space.lower,
                upper=domain.space.upper,
                batch_size=search.random.batch_size,
                seed=int(seeds[0]),
            )
        ]
    elif algorithm == "map_elites":
        settings = search.map_elites
        start = np.array(settings.x0, dtype=float) if settings.x0 is not None else x0(domain)
        emitters = [
            GaussianEmitter(
                archive,
                sigma=settings.sigma if settings.sigma is not None else sigma0(domain),
                x0=start,
                batch_size=settings.batch_size,
                seed=int(seeds[0]),
            )
        ]
    elif algorithm == "cma_mae":
        settings = search.emitter
        emitters = [
            EvolutionStrategyEmitter(
                archive,
                x0=x0(domain) if starts is None else starts[i],
                sigma0=sigma0(domain),
                **CMA_MAE_RULES,
                batch_size=settings.batch_size,
                seed=int(s),
            )
            for i, s in enumerate(seeds[1:])
        ]
    else:
        raise ValueError(f"{algorithm!r} is not a model-free algorithm; those are {', '.join(MODEL_FREE)}")
    return Scheduler(archive, emitters)


@functools.cache
def compile_cma_es() -> None:
    """Compiles pyribs' CMA-ES in this process, once, before a search's clock starts.

    numba compiles CMA-ES's sampling and update at their first call in a process (~3 s on these
    machines) and keeps nothing on disk. Paid inside a search, it fell on the first batch that ran
    CMA-ES: under ``--algorithm auto`` it was 2.4 of the 5.6 s of CMA-MAE's first measurement on
    teleoperation, which then scored as if CMA-MAE were half as fast as it is. It is start-up, like
    the imports, which a run's wall time does not count either. A two-dimensional search with the
    same emitter rules compiles the same code as any other (numba specialises on types, not sizes).
    """
    archive = GridArchive(solution_dim=2, dims=[2], ranges=[(0.0, 1.0)], learning_rate=0.01, threshold_min=0.0)
    emitter = EvolutionStrategyEmitter(
        archive,
        x0=np.zeros(2),
        sigma0=0.1,
        **CMA_MAE_RULES,
        batch_size=4,
        seed=0,
    )
    scheduler = Scheduler(archive, [emitter])
    solutions = scheduler.ask()
    scheduler.tell(np.ones(len(solutions)), np.abs(solutions[:, :1]) % 1.0)
