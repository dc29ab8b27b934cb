"""The repair problem: objects, the regions their centres may lie in, their pairwise constraints,
and what a repair returns."""

from __future__ import annotations

import dataclasses
import math

import numpy as np


class InfeasibleConstraints(ValueError):  # noqa: N818 (public name, caught by users)
    """No placement of the objects satisfies all of their constraints together."""


@dataclasses.dataclass(frozen=True, kw_only=True)
class Region:
    """An axis-aligned rectangle that an object's centre (not its whole footprint) must lie in.

    Args:
        name: Used in messages.
        x: ``(xlo, xhi)`` bounds of the centre, metres.
        y: ``(ylo, yhi)`` bounds of the centre, metres.

    Raises:
        ValueError: A bound is not finite or ``lo > hi``.
    """

    name: str
    x: tuple[float, float]
    y: tuple[float, float]

    def __post_init__(self) -> None:
        for axis in ("x", "y"):
            lo, hi = (float(v) for v in getattr(self, axis))
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise ValueError(
                    f"region {self.name!r}: {axis} must be (lo, hi) with finite "
                    f"lo <= hi, got {getattr(self, axis)!r}; swap the bounds"
                )
            object.__setattr__(self, axis, (lo, hi))


@dataclasses.dataclass(frozen=True, kw_only=True, eq=False)
class RepairProblem:
    """Objects with axis-aligned footprints and the constraints their centres must satisfy.

    Args:
        object_names: One name per object, used in messages.
        half_sizes: ``(n, 2)`` half extents of each footprint in x and y.
        regions: The rectangles that ``allowed_regions`` indexes.
        allowed_regions: Per object, indices into ``regions``; the centre must lie in at least one
            of them. An empty tuple means no region constraint for that object.
        no_overlap: Pairs whose footprints must not overlap (touching is allowed).
        min_separation: ``(i, j, d)``: the centres of ``i`` and ``j`` are at least ``d`` apart.
        bounds: ``(n, 2, 2)``; ``bounds[i, 0] = (xlo, xhi)`` and ``bounds[i, 1] = (ylo, yhi)``
            bound each centre.
        scales: ``(n, 2)`` positive lengths that count as one in the cost, per object and axis:
            the cost is ``sum(((moved) / scales) ** 2)``. Default: 1 m everywhere, a cost in m^2
            (the paper's); the width of each coordinate's bounds makes it a sum of squared
            fractions of the ranges the coordinates may vary over.

    Raises:
        ValueError: Shapes, indices or values are inconsistent; the message says which.
    """

    object_names: tuple[str, ...]
    half_sizes: np.ndarray
    regions: tuple[Region, ...]
    allowed_regions: tuple[tuple[int, ...], ...]
    no_overlap: tuple[tuple[int, int], ...] = ()
    min_separation: tuple[tuple[int, int, float], ...] = ()
    bounds: np.ndarray
    scales: np.ndarray | None = None

    def __post_init__(self) -> None:
        names = tuple(self.object_names)
        n = len(names)
        if n == 0 or len(set(names)) != n:
            raise ValueError(f"object_names must be non-empty and unique, got {names!r}")
        sizes = _frozen_array(self.half_sizes, (n, 2), "half_sizes")
        if (sizes < 0).any():
            raise ValueError(f"half_sizes must be >= 0, got {sizes.tolist()}")
        bounds = _frozen_array(self.bounds, (n, 2, 2), "bounds")
        if (bounds[:, :, 0] > bounds[:, :, 1]).any():
            raise ValueError("bounds[i, axis] must be (lo, hi) with lo <= hi; swap the bounds")
        scales = _frozen_array(np.ones((n, 2)) if self.scales is None else self.scales, (n, 2), "scales")
        if (scales <= 0).any():
            raise ValueError(f"scales must be > 0, got {scales.tolist()}")
        allowed = tuple(tuple(int(r) for r in a) for a in self.allowed_regions)
        if len(allowed) != n:
            raise ValueError(f"allowed_regions needs one tuple per object ({n}), got {len(allowed)}")
        if any(not 0 <= r < len(self.regions) for a in allowed for r in a):
            raise ValueError(f"allowed_regions {allowed} index past the {len(self.regions)} regions")
        pairs = tuple((int(i), int(j)) for i, j in self.no_overlap)
        seps = tuple((int(i), int(j), float(d)) for i, j, d in self.min_separation)
        for i, j, *distance in pairs + seps:
            if not (0 <= i < n and 0 <= j < n and i != j):
                raise ValueError(f"pair ({i}, {j}) must name two different objects in 0..{n - 1}")
            if distance and not (math.isfinite(distance[0]) and distance[0] > 0):
                raise ValueError(f"min_separation distance must be > 0, got {distance[0]}")
        for field, value in [
            ("object_names", names),
            ("half_sizes", sizes),
            ("bounds", bounds),
            ("scales", scales),
            ("regions", tuple(self.regions)),
            ("allowed_regions", allowed),
            ("no_overlap", pairs),
            ("min_separation", seps),
        ]:
            object.__setattr__(self, field, value)

    @property
    def n(self) -> int:
        """Number of objects."""
        return len(self.object_names)


@dataclasses.dataclass(frozen=True)
class RepairResult:
    """What :func:`repair` did.

    Attributes:
        xy: ``(n, 2)`` repaired centres (the input when nothing could be done).
        cost: Sum of squared displacements, each over its scale (``RepairProblem.scales``; in m^2
            by default), computed from ``xy``.
        regions: Per object, the index of the region it ends in (``None``: no region constraint,
            or no repair).
        status: ``"unchanged"``, ``"repaired"``, ``"infeasible"``, ``"timeout"`` or ``"error"``.
        message: Human-readable detail; says which stage produced a repair.
    """

    xy: np.ndarray
    cost: float
    regions: tuple[int | None, ...]
    status: str
    message: str = ""


def _frozen_array(value: object, shape: tuple[int, ...], name: str) -> np.ndarray:
    array = np.array(value, dtype=float)
    if array.shape != shape or not np.isfinite(array).all():
        raise ValueError(f"{name} must be a finite array of shape {shape}, got shape {array.shape}")
    array.setflags(write=False)
    return array
