"""The two archives of a search, and the numbers that summarise them.

The *result* archive keeps, per cell of the spec's measures, the scenario with the highest raw
objective: it is what the report shows and what QD-score is computed on. The *search* archive is
what the algorithm climbs: it sees the objective minus the weighted repair cost, uses CMA-MAE's
soft thresholds (learning rate alpha, threshold_min), and, where the repair places objects in
one of several regions, one extra axis per object for the region it landed in (the reference's
workspace-assignment measures), so that every assignment of objects to regions keeps its elites.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from ribs.archives import ArchiveBase, CVTArchive, GridArchive, k_means_centroids

from hritest.domain import Domain

CENTROID_SEED = 0  # a cvt archive's tessellation is the spec's: the same for every run


def result_archive(domain: Domain, *, seed: int) -> ArchiveBase:
    """Raw objective over the spec's measures; QD-score counts ``objective - range low`` per elite."""
    lo = domain.spec.objective.range[0]
    common = {
        "solution_dim": domain.space.dim,
        "ranges": domain.archive_ranges,
        "qd_score_offset": lo,
        "seed": seed,
        "extra_fields": {"evaluation": ((), np.int64)},
    }
    if domain.spec.archive.type == "cvt":
        return CVTArchive(centroids=centroids(domain), **common)
    return GridArchive(dims=domain.archive_dims, **common)


def search_archive(domain: Domain, *, seed: int) -> ArchiveBase:
    """Regularised objective, spec measures plus region axes; CMA-MAE thresholds from the spec."""
    settings = domain.spec.search.emitter
    regions = len(domain.repair.region_names)
    extra = len(workspace_objects(domain))
    common = {
        "solution_dim": domain.space.dim,
        "ranges": tuple(domain.archive_ranges) + ((-0.5, regions - 0.5),) * extra,
        "learning_rate": settings.learning_rate,
        "threshold_min": settings.threshold_min,
        "seed": seed,
    }
    if domain.spec.archive.type == "cvt":
        return CVTArchive(centroids=centroids(domain, regions=(regions,) * extra), **common)
    return GridArchive(dims=tuple(domain.archive_dims) + (regions,) * extra, **common)


def centroids(domain: Domain, *, cells: int | None = None, regions: tuple[int, ...] = ()) -> np.ndarray:
    """The cvt archive's centroids over the spec's measures (and ``regions``' axes, when the search
    archive has them), or ``cells`` of them. They depend on the spec alone, not on a run's seed: every
    run of a spec shares one tessellation, so runs compare cell for cell."""
    spec = domain.spec.archive
    ranges = tuple(domain.archive_ranges) + tuple((-0.5, n - 0.5) for n in regions)
    return tessellation(cells or spec.cells, ranges, spec.samples)


@functools.lru_cache(maxsize=16)
def tessellation(cells: int, ranges: tuple[tuple[float, float], ...], samples: int) -> np.ndarray:
    """``cells`` centroids over ``ranges`` by k-means on ``samples`` uniform points (read-only)."""
    found, _ = k_means_centroids(centroids=cells, ranges=ranges, samples=samples, seed=CENTROID_SEED)
    found.setflags(write=False)
    return found


def workspace_objects(domain: Domain) -> tuple[str, ...]:
    """Objects that get a region axis: those the repair places, when there is a choice of regions."""
    return domain.repair.objects if len(domain.repair.region_names) > 1 else ()


def elite_objectives(archive: ArchiveBase, measures: np.ndarray, *, empty: float) -> np.ndarray:
    """The objective of ``archive``'s elite in the cell of each row of ``measures`` (``empty``
    where it has none): what a new scenario there must beat to add to the QD-score."""
    occupied, data = archive.retrieve(measures)
    return np.where(occupied, data["objective"], empty)


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
    def of(cls, archive: ArchiveBase, objective_range: tuple[float, float]) -> Summary:
        stats = archive.stats
        span = objective_range[1] - objective_range[0]
        return cls(
            qd_score=float(stats.qd_score),
            normalized_qd_score=float(stats.qd_score) / (archive.cells * span),
            coverage=float(stats.coverage),
            best=float(stats.obj_max) if stats.obj_max is not None else float("nan"),
            elites=int(stats.num_elites),
        )
