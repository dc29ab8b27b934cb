"""The report's figures, drawn with matplotlib's Agg backend and returned as PNG bytes.

The archive heatmap draws what pyribs' ``grid_archive_heatmap`` draws (the best objective of
each cell of a ``GridArchive`` as a ``pcolormesh`` over the cell boundaries, empty cells blank),
on a ribs ``GridArchive`` rebuilt from the run's elites. It does not call that function because
``ribs.visualize`` 0.12 imports seaborn when it is imported, and hritest does not depend on it.
"""

from __future__ import annotations

import io
import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import matplotlib

matplotlib.use("Agg")  # before pyplot: no display, same pixels everywhere

import matplotlib.pyplot as plt
import numpy as np
from ribs.archives import GridArchive
from scipy.spatial import cKDTree

CMAP = "viridis"
_PIXELS = 400  # per side of a cvt archive's drawing
DPI = 110
_FAILURE = "#e8251f"
_KINDS = ("#e8251f", "#ff9f1c", "#ffffff", "#f72585", "#4cc9f0")  # kinds of failure: apart on viridis
_EMPTY = "#e9e9ec"
plt.rcParams.update({"font.size": 10, "axes.titlesize": 11, "axes.labelsize": 10, "figure.autolayout": False})


@dataclass(frozen=True)
class ArchiveView:
    """What a heatmap shows: the elites of a result archive and the failures to mark on it.

    ``elites`` and ``failures`` are ``(objective, measures)`` and ``(id, measures)`` pairs;
    ``labelled`` names the failure ids to write beside their marks; ``kinds`` maps a failure's id
    to its kind (1, 2, ...), which colours its mark (all red without).
    """

    title: str
    measure_names: Sequence[str]
    ranges: Sequence[tuple[float, float]]
    cells: Sequence[int]
    objective_range: tuple[float, float]
    objective_label: str
    elites: Sequence[tuple[float, Sequence[float]]]
    failures: Sequence[tuple[int, Sequence[float]]] = ()
    labelled: Sequence[int] = field(default_factory=tuple)
    kinds: Mapping[int, int] = field(default_factory=dict)
    centroids: np.ndarray | None = None  # a cvt archive's (cells, measures); None: a grid of ``cells``


def archive_heatmap(view: ArchiveView) -> bytes:
    """One archive as a heatmap of its best objective per cell, failures marked; with three or
    more measures (a cvt archive), its elites projected on each pair of measures."""
    if len(view.measure_names) <= 2:
        fig, ax = plt.subplots(figsize=(8.6, 5.6))
        _draw_archive(ax, view)
        return _png(fig)
    pairs = list(itertools.combinations(range(len(view.measure_names)), 2))
    columns = min(3, len(pairs))
    rows = -(-len(pairs) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(5.2 * columns, 4.3 * rows), squeeze=False)
    for ax, pair in zip(axes.flat, pairs):
        _draw_projection(ax, view, pair)
    for ax in axes.flat[len(pairs) :]:
        ax.set_visible(False)
    fig.suptitle(view.title)
    return _png(fig)


def archive_heatmaps(views: Sequence[ArchiveView]) -> bytes:
    """Several archives side by side (at most three a row), for comparing runs."""
    columns = min(3, len(views))
    rows = -(-len(views) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(5.2 * columns, 4.3 * rows), squeeze=False)
    for ax, view in zip(axes.flat, views):
        _draw_archive(ax, view)
    for ax in axes.flat[len(views) :]:
        ax.set_visible(False)
    return _png(fig)


def qd_curves(series: Sequence[tuple[str, Sequence[dict]]], *, normalised: bool = False) -> bytes:
    """QD-score against evaluations and against wall time, one line per run.

    Args:
        series: ``(label, progress rows)``; each row has ``evaluations``, ``wall_time``,
            ``qd_score`` and ``normalized_qd_score`` (as in ``progress.csv``).
        normalised: plot the normalised QD-score (for runs of different specs).
    """
    key = "normalized_qd_score" if normalised else "qd_score"
    fig, (left, right) = plt.subplots(1, 2, figsize=(11.0, 3.8))
    for i, (label, rows) in enumerate(series):
        colour = f"C{i}"
        evaluations = [0.0] + [float(r["evaluations"]) for r in rows]
        seconds = [0.0] + [float(r["wall_time"]) for r in rows]
        score = [0.0] + [float(r[key]) for r in rows]
        style = {"color": colour, "marker": "o", "markersize": 3.5, "linewidth": 1.6, "label": label}
        left.plot(evaluations, score, **style)
        right.plot(seconds, score, **style)
    name = "normalised QD-score" if normalised else "QD-score"
    for ax, xlabel in ((left, "evaluations"), (right, "wall time (s)")):
        ax.set_xlabel(xlabel)
        ax.set_ylabel(name)
        ax.set_xlim(left=0)
        ax.set_ylim(bottom=0)
        ax.grid(True, alpha=0.3)
    left.set_title(f"{name} against evaluations")
    right.set_title(f"{name} against wall time")
    if len(series) > 1:
        left.legend(loc="lower right", fontsize=9)
    return _png(fig)


def _draw_archive(ax: plt.Axes, view: ArchiveView) -> None:
    if view.centroids is not None:
        if len(view.measure_names) == 2:
            _draw_voronoi(ax, view)
        else:
            _draw_projection(ax, view, (0, 1) if len(view.measure_names) > 1 else (0, 0))
        return
    dims = min(2, len(view.cells))
    archive = _archive(view, dims)
    lo, hi = view.objective_range
    values = np.full(archive.cells, np.nan)
    data = archive.data(["index", "objective"])
    values[data["index"]] = data["objective"]
    if dims == 1:
        mesh = ax.pcolormesh(archive.boundaries[0], [0.0, 1.0], values[None, :], cmap=CMAP, vmin=lo, vmax=hi)
        ax.set_yticks([])
        ax.set_xlim(*view.ranges[0])
    else:
        grid = np.full((archive.dims[1], archive.dims[0]), np.nan)
        index = archive.int_to_grid_index(data["index"])
        grid[index[:, 1], index[:, 0]] = data["objective"]
        mesh = ax.pcolormesh(archive.boundaries[0], archive.boundaries[1], grid, cmap=CMAP, vmin=lo, vmax=hi)
        ax.set_xlim(*view.ranges[0])
        ax.set_ylim(*view.ranges[1])
        ax.set_ylabel(view.measure_names[1])
    ax.set_facecolor(_EMPTY)
    ax.set_xlabel(view.measure_names[0])
    ax.set_title(view.title)
    bar = ax.figure.colorbar(mesh, ax=ax, pad=0.02)
    bar.set_label(view.objective_label)
    _mark_failures(ax, view, dims)


def _draw_voronoi(ax: plt.Axes, view: ArchiveView) -> None:
    """A two-measure cvt archive: each cell (the points nearest its centroid) coloured by its elite."""
    (x0, x1), (y0, y1) = view.ranges[:2]
    lo, hi = view.objective_range
    best = np.full(len(view.centroids), np.nan)
    if view.elites:
        measures = np.array([m[:2] for _, m in view.elites], dtype=float)
        cells = cKDTree(view.centroids).query(measures)[1]
        np.fmax.at(best, cells, np.array([o for o, _ in view.elites], dtype=float))
    xs, ys = np.linspace(x0, x1, _PIXELS), np.linspace(y0, y1, _PIXELS)
    pixels = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    image = best[cKDTree(view.centroids).query(pixels)[1]].reshape(_PIXELS, _PIXELS)
    mesh = ax.imshow(image, origin="lower", extent=(x0, x1, y0, y1), aspect="auto", cmap=CMAP, vmin=lo, vmax=hi)
    ax.scatter(view.centroids[:, 0], view.centroids[:, 1], s=1, color="#9a9aa3", zorder=2)
    _frame(ax, view, (0, 1), mesh)


def _draw_projection(ax: plt.Axes, view: ArchiveView, pair: tuple[int, int]) -> None:
    """A cvt archive's elites on two of its measures, coloured by objective."""
    lo, hi = view.objective_range
    i, j = pair
    points = np.array([[m[i], m[j]] for _, m in view.elites], dtype=float).reshape(-1, 2)
    objectives = np.array([o for o, _ in view.elites], dtype=float)
    mesh = ax.scatter(points[:, 0], points[:, 1], c=objectives, s=9, cmap=CMAP, vmin=lo, vmax=hi, zorder=2)
    _frame(ax, view, pair, mesh)


def _frame(ax: plt.Axes, view: ArchiveView, pair: tuple[int, int], mesh: Any) -> None:
    i, j = pair
    ax.set_xlim(*view.ranges[i])
    ax.set_ylim(*view.ranges[j])
    ax.set_xlabel(view.measure_names[i])
    ax.set_ylabel(view.measure_names[j])
    ax.set_facecolor(_EMPTY)
    ax.set_title(view.title if len(view.measure_names) <= 2 else f"{view.measure_names[i]} x {view.measure_names[j]}")
    bar = ax.figure.colorbar(mesh, ax=ax, pad=0.02)
    bar.set_label(view.objective_label)
    _mark_failures(ax, view, 2, pair)


def _mark_failures(ax: plt.Axes, view: ArchiveView, dims: int, pair: tuple[int, int] = (0, 1)) -> None:
    if not view.failures:
        return
    axes = list(pair[:dims])
    ranges = np.array([view.ranges[a] for a in axes], dtype=float)
    points = np.array([[m[a] for a in axes] for _, m in view.failures], dtype=float)
    points = np.clip(points, ranges[:, 0], ranges[:, 1])
    if dims == 1:
        points = np.column_stack([points[:, 0], np.full(len(points), 0.5)])
    kinds = np.array([view.kinds.get(fid, 0) for fid, _ in view.failures])
    for kind in np.unique(kinds):
        mine = kinds == kind
        ax.scatter(
            points[mine, 0],
            points[mine, 1],
            s=30,
            facecolors="none",
            edgecolors=_FAILURE if kind == 0 else _KINDS[(kind - 1) % len(_KINDS)],
            linewidths=1.3,
            label=f"failure ({mine.sum()})" if kind == 0 else f"kind {kind} ({mine.sum()})",
            zorder=3,
        )
    labelled = set(view.labelled)
    for (fid, _), (x, y) in zip(view.failures, points):
        if fid in labelled:
            ax.annotate(
                str(fid),
                (x, y),
                xytext=(5, 5),
                textcoords="offset points",
                fontsize=8,
                color="white",
                bbox={"boxstyle": "round,pad=0.15", "fc": "#8a1512", "ec": "none", "alpha": 0.9},
                zorder=4,
            )
    ax.legend(loc="upper right", fontsize=8, framealpha=0.85)


def _archive(view: ArchiveView, dims: int) -> GridArchive:
    """A ribs GridArchive over the first ``dims`` measures holding the view's elites."""
    archive = GridArchive(
        solution_dim=1,
        dims=tuple(view.cells[:dims]),
        ranges=tuple(view.ranges[:dims]),
        qd_score_offset=view.objective_range[0],
    )
    if view.elites:
        objectives = np.array([o for o, _ in view.elites], dtype=float)
        measures = np.array([m[:dims] for _, m in view.elites], dtype=float)
        archive.add(np.zeros((len(objectives), 1)), objectives, measures)
    return archive


def _png(fig: plt.Figure) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return buffer.getvalue()
