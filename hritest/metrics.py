"""Metric building blocks computed from a rollout's arrays: pure numpy, shared by all tasks."""

from __future__ import annotations

import itertools

import numpy as np

GRID_CELLS = 32


def path_length(points: np.ndarray) -> float:
    """Sum of the distances between consecutive points (the paper's discrete path integral)."""
    points = np.asarray(points, dtype=float)
    if len(points) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def min_pairwise_distance(points: np.ndarray) -> float:
    """Smallest Euclidean distance between any two of the points (goals' x, y)."""
    points = np.asarray(points, dtype=float)
    return min(float(np.linalg.norm(a - b)) for a, b in itertools.combinations(points, 2))


def occupancy_grid(
    xy: np.ndarray, *, x: tuple[float, float], y: tuple[float, float], cells: int = GRID_CELLS
) -> np.ndarray:
    """Where an agent spent its ticks: a ``cells x cells`` histogram over the extent, summing to 1.

    Follows the reference's binning exactly (``int(clip((n * (p - lo) + 1e-9) / (hi - lo), 0, n-1))``,
    first index from x), so that a surrogate trained here predicts the same quantity as the paper's.
    """
    xy = np.asarray(xy, dtype=float)[:, :2]
    lo = np.array([x[0], y[0]])
    hi = np.array([x[1], y[1]])
    index = np.clip((cells * (xy - lo) + 1e-9) / (hi - lo), 0, cells - 1).astype(int)
    grid = np.zeros((cells, cells))
    np.add.at(grid, (index[:, 0], index[:, 1]), 1.0)
    return grid / max(len(xy), 1)
