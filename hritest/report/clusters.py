"""The kinds of failure in a run: its failures clustered by how they behaved (pure).

A report of 200 failures is read as a few kinds. Each failure is described by its measures
(over their ranges), its objective, every metric the task reports (the trajectory's features) and
which clauses of the failure condition held; the columns are standardised and clustered with
k-means (scipy), k from 1 to :data:`MOST` chosen by the silhouette. Each cluster is represented
by its worst failure and described by the features that set it apart from the other failures.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.cluster.vq import kmeans2

from hritest.records import EvaluationRecord, rank_failures

MOST = 5  # clusters at most: more kinds than this are not read as kinds
FEWEST = 6  # failures below this are one cluster: too few to tell kinds apart
SEPARATED = 0.6  # the silhouette a split must reach to be kinds: structureless noise reaches ~0.55
TRAITS = 2  # features named per cluster


@dataclass(frozen=True)
class Cluster:
    """Failures that behaved alike: worst first, the first being the representative."""

    members: tuple[EvaluationRecord, ...]
    traits: tuple[str, ...]  # what sets the cluster apart, in words

    @property
    def representative(self) -> EvaluationRecord:
        return self.members[0]


def cluster_failures(
    failures: Sequence[EvaluationRecord],
    *,
    measure_names: Sequence[str],
    ranges: Sequence[tuple[float, float]],
    seed: int = 0,
) -> list[Cluster]:
    """The failures' clusters, largest first (ties: the one with the worse representative)."""
    ranked = rank_failures(failures)
    if not ranked:
        return []
    names, features = _features(ranked, measure_names, ranges)
    labels = _labels(features, seed)
    clusters = []
    for label in np.unique(labels):
        inside = labels == label
        members = tuple(r for r, keep in zip(ranked, inside) if keep)  # ranked order: worst first
        traits = _traits(names, features, inside) if len(np.unique(labels)) > 1 else ()
        clusters.append(Cluster(members=members, traits=traits))
    order = {r.index: i for i, r in enumerate(ranked)}
    return sorted(clusters, key=lambda c: (-len(c.members), order[c.representative.index]))


def _features(
    ranked: Sequence[EvaluationRecord], measure_names: Sequence[str], ranges: Sequence[tuple[float, float]]
) -> tuple[list[tuple[str, str]], np.ndarray]:
    """``(kind, name)`` of each column, and the rows: measures, objective, metrics, clauses."""
    names: list[tuple[str, str]] = [("measure", m) for m in measure_names] + [("objective", "objective")]
    rows = [[_scaled(v, lo, hi) for v, (lo, hi) in zip(r.measures, ranges)] + [_finite(r.objective)] for r in ranked]
    metrics = sorted({k for r in ranked for k in r.metrics})
    clauses = sorted({c.text for r in ranked for c in r.fired})
    names += [("metric", m) for m in metrics] + [("clause", c) for c in clauses]
    for row, r in zip(rows, ranked):
        fired = {c.text for c in r.fired}
        row.extend([_finite(r.metrics.get(m, math.nan)) for m in metrics] + [float(c in fired) for c in clauses])
    return names, np.array(rows, dtype=float).reshape(len(ranked), len(names))


def _labels(features: np.ndarray, seed: int) -> np.ndarray:
    """k-means labels of the standardised features, k chosen by the silhouette (1 if none separates)."""
    n = len(features)
    spread = features.std(axis=0)
    data = (features[:, spread > 1e-12] - features[:, spread > 1e-12].mean(axis=0)) / spread[spread > 1e-12]
    if n < FEWEST or data.shape[1] == 0:
        return np.zeros(n, dtype=int)
    best, labels = SEPARATED, np.zeros(n, dtype=int)
    for k in range(2, min(MOST, n - 1) + 1):
        _, found = kmeans2(data, k, minit="++", seed=np.random.default_rng([seed, k]))
        if len(np.unique(found)) < 2:
            continue
        score = _silhouette(data, found)
        if score > best:
            best, labels = score, found
    return labels


def _silhouette(data: np.ndarray, labels: np.ndarray) -> float:
    """The mean silhouette coefficient (Rousseeuw 1987) of a clustering."""
    distances = np.linalg.norm(data[:, None, :] - data[None, :, :], axis=-1)
    scores = []
    for i, label in enumerate(labels):
        own = labels == label
        if own.sum() < 2:
            scores.append(0.0)
            continue
        a = distances[i, own].sum() / (own.sum() - 1)
        b = min(distances[i, labels == other].mean() for other in np.unique(labels) if other != label)
        scores.append((b - a) / max(a, b) if max(a, b) > 0 else 0.0)
    return float(np.mean(scores))


def _traits(names: list[tuple[str, str]], features: np.ndarray, inside: np.ndarray) -> tuple[str, ...]:
    """The features whose mean in the cluster lies farthest from the other failures' mean."""
    spread = features.std(axis=0)
    ours, theirs = features[inside].mean(axis=0), features[~inside].mean(axis=0)
    gap = np.where(spread > 1e-12, (ours - theirs) / np.where(spread > 1e-12, spread, 1.0), 0.0)
    traits = []
    order = np.lexsort((-gap, -np.round(np.abs(gap), 9)))  # ties: what the cluster has, before what it lacks
    for column in order[:TRAITS]:
        if abs(gap[column]) < 0.5:
            break
        kind, name = names[column]
        if kind == "clause":
            traits.append(f"'{name}' holds in {ours[column]:.0%} (others {theirs[column]:.0%})")
        else:
            unit = " of its range" if kind == "measure" else ""
            word = "high" if gap[column] > 0 else "low"
            traits.append(f"{name} {word}: {ours[column]:.3g}{unit} (others {theirs[column]:.3g})")
    return tuple(traits)


def _scaled(value: float, lo: float, hi: float) -> float:
    return (value - lo) / (hi - lo) if math.isfinite(value) and hi > lo else 0.0


def _finite(value: float) -> float:
    return value if math.isfinite(value) else 0.0
