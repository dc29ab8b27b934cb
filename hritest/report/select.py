"""Which failures a report shows and records: pure functions of the records."""

from __future__ import annotations

import math
from collections.abc import Sequence

from hritest.records import EvaluationRecord, rank_failures, worst_of_each_clause

SPLITS = 3  # blocks per measure when picking the most different failures
_BLOCK_NAMES = {2: ("low", "high"), 3: ("low", "mid", "high")}


def worst_failures(failures: Sequence[EvaluationRecord], count: int) -> list[EvaluationRecord]:
    """The ``count`` worst failures, in :func:`hritest.records.rank_failures`' order."""
    return rank_failures(failures)[: max(count, 0)]


def most_different(
    failures: Sequence[EvaluationRecord], ranges: Sequence[tuple[float, float]], splits: int = SPLITS
) -> list[tuple[str, EvaluationRecord]]:
    """The worst failure in each block of the measure space, each measure's range cut in ``splits``.

    Returns ``(block, failure)`` pairs in block order, e.g. ``("low / high", record)``: the
    failure whose first measure lies in the lowest third of its range and second in the highest.
    """
    names = _BLOCK_NAMES.get(splits, tuple(str(i + 1) for i in range(splits)))
    best: dict[tuple[int, ...], EvaluationRecord] = {}
    for record in worst_failures(failures, len(failures)):
        block = tuple(_block(v, lo, hi, splits) for v, (lo, hi) in zip(record.measures, ranges))
        best.setdefault(block, record)
    return [(" / ".join(names[i] for i in block), best[block]) for block in sorted(best)]


def _block(value: float, lo: float, hi: float, splits: int) -> int:
    if not math.isfinite(value) or hi <= lo:
        return 0
    return int(min(max((value - lo) / (hi - lo) * splits, 0), splits - 1))


def chosen_failures(
    failures: Sequence[EvaluationRecord], ranges: Sequence[tuple[float, float]], count: int
) -> list[EvaluationRecord]:
    """The failures to record: the ``count`` worst, the worst of each failure clause and the most
    different ones (none when 0): every failure the report's tables show."""
    if count <= 0:
        return []
    chosen = {r.index: r for r in worst_failures(failures, count)}
    for record in [
        *worst_of_each_clause(rank_failures(failures)).values(),
        *(r for _, r in most_different(failures, ranges)),
    ]:
        chosen.setdefault(record.index, record)
    return list(chosen.values())
