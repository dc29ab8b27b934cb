"""What a surrogate learns from, kept compact: the search never holds every evaluation record.

A long model-free run keeps no evaluation in memory beyond its archive's elites (see
:class:`~hritest.search.loop.Search`); a surrogate needs every successful one's theta and
targets, which :class:`TrainingData` keeps as float32 rows (tens of bytes each, not the kilobytes
of a record), and their occupancy grids, which stay in the run directory's ``occupancy.f32``,
memory-mapped, and are read only for the rows a training round uses (:class:`GridRows`).
"""

from __future__ import annotations

import numpy as np


class TrainingData:
    """Per successful evaluation, in the order they finished: its index, its line in the run's
    files, raw theta and targets. Grows by doubling, so an append costs amortised O(1)."""

    def __init__(self, *, dim: int, outputs: int) -> None:
        self.size = 0
        self.index = np.zeros(1024, np.int64)
        self.line = np.zeros(1024, np.int64)
        self.theta = np.zeros((1024, dim), np.float32)
        self.targets = np.zeros((1024, outputs), np.float32)

    def __len__(self) -> int:
        return self.size

    def append(self, *, index: int, line: int, theta: np.ndarray, targets: list[float]) -> None:
        if self.size == len(self.index):
            for name in ("index", "line", "theta", "targets"):
                old = getattr(self, name)
                grown = np.zeros((2 * len(old), *old.shape[1:]), old.dtype)
                grown[: len(old)] = old
                setattr(self, name, grown)
        self.index[self.size], self.line[self.size] = index, line
        self.theta[self.size], self.targets[self.size] = theta, targets
        self.size += 1

    def in_evaluation_order(self, before: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(theta, targets, lines)`` sorted by evaluation index, not by when workers finished:
        so training, and so the run, is the same whatever the number of workers. Copies: later
        appends do not change them. With ``before``, only the evaluations of lower index."""
        index = self.index[: self.size]
        order = np.argsort(index, kind="stable")
        if before is not None:
            order = order[index[order] < before]
        return self.theta[order], self.targets[order], self.line[order]


class GridRows:
    """The occupancy grids of some lines of ``occupancy.f32``, read only when indexed.

    ``grids[rows]`` reads those rows from the memory-mapped file; ``np.asarray(grids)`` reads all.
    """

    def __init__(self, grids: np.ndarray, lines: np.ndarray) -> None:
        self.grids, self.lines = grids, lines
        self.shape = (len(lines), *grids.shape[1:])

    def __len__(self) -> int:
        return len(self.lines)

    def __getitem__(self, rows: np.ndarray) -> np.ndarray:
        return np.asarray(self.grids[self.lines[rows]])

    def __array__(self, dtype: np.dtype | None = None, copy: bool | None = None) -> np.ndarray:
        return np.asarray(self.grids[self.lines], dtype=dtype)
