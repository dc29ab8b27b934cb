"""Which failures a report shows and records: pure functions of the records."""

from __future__ import annotations

from collections.abc import Sequence

from hritest.records import EvaluationRecord, rank_failures, worst_of_each_clause
from hritest.report.clusters import Cluster


def worst_failures(failures: Sequence[EvaluationRecord], count: int) -> list[EvaluationRecord]:
    """The ``count`` worst failures, in :func:`hritest.records.rank_failures`' order."""
    return rank_failures(failures)[: max(count, 0)]


def chosen_failures(
    failures: Sequence[EvaluationRecord], clusters: Sequence[Cluster], count: int
) -> list[EvaluationRecord]:
    """The failures to record: the ``count`` worst, the worst of each failure clause and each
    kind's representative (none when 0): every failure the report's tables show."""
    if count <= 0:
        return []
    chosen = {r.index: r for r in worst_failures(failures, count)}
    for record in [*worst_of_each_clause(rank_failures(failures)).values(), *(c.representative for c in clusters)]:
        chosen.setdefault(record.index, record)
    return list(chosen.values())
