"""The two archives of a search, and the numbers that summarise them.

The *result* archive keeps, per cell of the spec's measures, the scenario with the highest raw
objective: it is what the report shows and what QD-score is computed on. The *search* archive is
what the algorithm climbs: it sees the objective minus the weighted repair cost, uses CMA-MAE's
soft thresholds (learning rate alpha, threshold_min), and, where the repair places objects in
one of several regions, one extra axis per object for the region it landed in (the reference's
workspace-assignment measures), so that every assignment of objects to regions keeps its elites.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ribs.archives import GridArchive

from hritest.domain import Domain


def result_archive(domain: Domain, *, seed: int) -> GridArchive:
    """Raw objective over the spec's measures; QD-score counts ``objective - range low`` per elite."""
    lo = domain.spec.objective.range[0]
    return GridArchive(
        solution_dim=domain.space.dim,
        dims=domain.archive_dims,
        ranges=domain.archive_ranges,
        qd_score_offset=lo,
        seed=seed,
        extra_fields={"evaluation": ((), np.int64)},
    )


def search_archive(domain: Domain, *, seed: int, dims: tuple[int, ...] | None = None) -> GridArchive:
    """Regularised objective, spec measures plus region axes; CMA-MAE thresholds from the spec.

    Args:
        dims: cells per spec measure (default: the spec's); the region axes are appended.
    """
    settings = domain.spec.search.emitter
    regions = len(domain.repair.region_names)
    extra = len(workspace_objects(domain))
    return GridArchive(
        solution_dim=domain.space.dim,
        dims=tuple(dims or domain.archive_dims) + (regions,) * extra,
        ranges=tuple(domain.archive_ranges) + ((-0.5, regions - 0.5),) * extra,
        learning_rate=settings.learning_rate,
        threshold_min=settings.threshold_min,
        seed=seed,
    )


def workspace_objects(domain: Domain) -> tuple[str, ...]:
    """Objects that get a region axis: those the repair places, when there is a choice of regions."""
    return domain.repair.objects if len(domain.repair.region_names) > 1 else ()


def region_measures(domain: Domain, regions: list[dict[str, str | None]]) -> np.ndarray:
    """``(n, objects)`` region index of each placed object (the search archive's extra axes)."""
    names = workspace_objects(domain)
    index = {name: i for i, name in enumerate(domain.repair.region_names)}
    return np.array([[index.get(r.get(name), 0) for name in names] for r in regions], dtype=float).reshape(
        len(regions), len(names)
    )


@dataclass(frozen=True)
class Summary:
    """What one line of the progress log says about the result archive."""

    qd_score: float
    normalized_qd_score: float
    coverage: float
    best: float
    elites: int

    @classmethod
    def of(cls, archive: GridArchive, objective_range: tuple[float, float]) -> Summary:
        stats = archive.stats
        span = objective_range[1] - objective_range[0]
        return cls(
            qd_score=float(stats.qd_score),
            normalized_qd_score=float(stats.qd_score) / (archive.cells * span),
            coverage=float(stats.coverage),
            best=float(stats.obj_max) if stats.obj_max is not None else float("nan"),
            elites=int(stats.num_elites),
        )
