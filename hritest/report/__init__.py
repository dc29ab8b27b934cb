"""The failure report of a run directory, and a comparison of several runs.

``write_report(run)`` writes ``<run>/report/index.html`` (one self-contained page) and
``<run>/report/summary.md`` (with its figures as PNG files beside it), and re-simulates the
reported failures into Rerun recordings under ``<run>/recordings/``. ``compare_runs(runs, out)``
puts several runs on one set of curves and heatmaps.

A report reads a run once (:mod:`.run`), selects failures with pure functions (:mod:`.select`),
records them (:mod:`.recordings`), builds a document (:mod:`.document`, out of :mod:`.html`'s
blocks and :mod:`.figures`' plots), and writes it (here).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from hritest.report.clusters import Cluster, cluster_failures
from hritest.report.contrast import contrast
from hritest.report.document import RECORDINGS, compare_document, run_document
from hritest.report.html import Document, to_html, to_markdown
from hritest.report.recordings import Recorded, record_failures
from hritest.report.run import RunData, load_run
from hritest.report.select import chosen_failures, worst_failures
from hritest.rundir import atomic_write

__all__ = [
    "Cluster",
    "RunData",
    "chosen_failures",
    "cluster_failures",
    "compare_runs",
    "load_run",
    "worst_failures",
    "write_report",
]


def write_report(run_path: Path, *, recordings: int = RECORDINGS, out: Path | None = None, trust: bool = False) -> Path:
    """Writes the report of a run directory; returns the path of its ``index.html``.

    Args:
        run_path: the run directory.
        recordings: record this many worst failures, plus the worst of each failure clause and
            each kind's representative, and look for the first kind's counterfactual (0: record
            and search nothing, but show what earlier reports left).
        out: the report folder (default ``<run>/report``).
        trust: load the run's checkpoint and plugin files though another user wrote them
            (see :mod:`hritest.rundir`); the run is not signed as this user's.

    Raises:
        RunDirectoryError, EmptyRunError: not a readable run, one with no evaluations, or one
            another user wrote (unless ``trust``).
        RecordingError: the recordings folder cannot be written.
    """
    data = load_run(run_path, trust=trust)
    out = Path(out) if out is not None else data.path / "report"
    out.mkdir(parents=True, exist_ok=True)
    recorded = record_failures(data, chosen_failures(data.failures, data.clusters, recordings))
    for r in data.failures:  # link what earlier reports or replays recorded
        earlier = data.path / "recordings" / f"{r.index}.rrd"
        if r.index not in recorded and earlier.is_file():
            recorded[r.index] = Recorded(earlier, None)
    against = contrast(data, data.clusters[0].representative, search=recordings > 0) if data.clusters else None
    doc = run_document(data, recorded, link_base=out, worst_count=max(recordings, RECORDINGS), contrast=against)
    _write(doc, out)
    return out / "index.html"


def compare_runs(run_paths: Sequence[Path], out: Path, *, trust: bool = False) -> Path:
    """One page that puts several runs on the same curves and their archives side by side
    (``trust``: as :func:`write_report`).

    Raises:
        RunDirectoryError, EmptyRunError: any run that is not readable or has no evaluations.
    """
    runs = [load_run(p, trust=trust) for p in run_paths]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    _write(compare_document(runs, link_base=out), out)
    return out / "index.html"


def _write(doc: Document, out: Path) -> None:
    for figure in doc.figures():
        atomic_write(out / figure.name, figure.png)
    atomic_write(out / "summary.md", to_markdown(doc))
    atomic_write(out / "index.html", to_html(doc))
