"""The repair of box-bounded parameters: clipping, with the reference's grouped cost."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def clip_repair(
    theta: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    groups: Sequence[Sequence[int]] | None = None,
    *,
    scale: np.ndarray | None = None,
) -> tuple[np.ndarray, float]:
    """Clips ``theta`` into ``[lo, hi]`` and returns the reference's clipping cost.

    The cost is the reference's definition (``clip_one_ws`` in ``dsas``): per group of components,
    the excesses (distance outside the bounds, >= 0) are summed, the sum is squared, and the
    squares are added. Groups exist to reproduce that number, which is not a sum of squares: the
    teleoperation domain groups the goals' x coordinates, their y coordinates and the waypoint
    noises, giving ``(sum e_x)^2 + (sum e_y)^2 + (sum e_noise)^2``. ``groups=None``, or a
    component listed in no group, makes each component its own group (a plain sum of squares).
    Each excess is first divided by its component's ``scale``, so that components in different
    units (metres, seconds) can be measured alike, as fractions of their bounds' widths, say.

    Args:
        theta: ``(d,)`` or ``(batch, d)``.
        lo: ``(d,)`` lower bounds.
        hi: ``(d,)`` upper bounds.
        groups: Disjoint lists of component indices.
        scale: ``(d,)`` positive lengths that count as one in each component's excess (default:
            1, theta's own units, the reference's cost).

    Returns:
        The clipped ``theta`` (same shape) and the cost, of shape ``()`` or ``(batch,)``.

    Raises:
        ValueError: Shapes disagree, ``lo > hi``, a scale is not positive, or a group index is out
            of range or repeated.
    """
    theta = np.asarray(theta, dtype=float)
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    d = theta.shape[-1] if theta.ndim else -1
    if theta.ndim not in (1, 2) or lo.shape != (d,) or hi.shape != (d,):
        raise ValueError(
            f"theta must be (d,) or (batch, d) with lo and hi of shape (d,); got "
            f"{theta.shape}, {lo.shape} and {hi.shape}"
        )
    if (lo > hi).any():
        raise ValueError(f"lo must be <= hi; components {np.flatnonzero(lo > hi).tolist()} are not")
    scale = np.ones(d) if scale is None else np.asarray(scale, dtype=float)
    if scale.shape != (d,) or not (scale > 0).all() or not np.isfinite(scale).all():
        raise ValueError(f"scale must be {d} positive finite lengths, one per component; got {scale.tolist()}")
    excess = (np.maximum(lo - theta, 0.0) + np.maximum(theta - hi, 0.0)) / scale
    cost = ((excess @ _membership(groups, d).T) ** 2).sum(axis=-1)
    return np.clip(theta, lo, hi), cost[()] if theta.ndim == 1 else cost


def _membership(groups: Sequence[Sequence[int]] | None, d: int) -> np.ndarray:
    """``(n_groups, d)`` 0/1 matrix; unlisted components become groups of their own."""
    rows, seen = [], set()
    for g in groups or ():
        indices = [int(k) for k in g]
        if any(not 0 <= k < d for k in indices) or seen & set(indices) or len(set(indices)) != len(indices):
            raise ValueError(f"groups must be disjoint lists of indices in 0..{d - 1}, got {groups}")
        seen |= set(indices)
        rows.append(np.isin(np.arange(d), indices).astype(float))
    rows += [np.eye(d)[k] for k in range(d) if k not in seen]
    return np.array(rows).reshape(-1, d)
