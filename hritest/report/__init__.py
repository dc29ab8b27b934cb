"""The failure report of a run directory, and a comparison of several runs.

``write_report(run)`` writes ``<run>/report/index.html`` (one self-contained page) and
``<run>/report/summary.md`` (with its figures as PNG files beside it), and re-simulates the
reported failures into Rerun recordings under ``<run>/recordings/``. ``compare_runs(runs, out)``
puts several runs on one set of curves and heatmaps.

The module reads a run once (:func:`load_run`), selects failures with pure functions
(:func:`worst_failures`, :func:`most_different`), builds a document (:mod:`.html`) with figures
(:mod:`.figures`), and writes it.
"""

from __future__ import annotations

import csv
import json
import math
import os
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hritest.records import EvaluationRecord, clauses_text, rank_failures, worst_of_each_clause
from hritest.report import figures
from hritest.report.html import Badge, Code, Details, Document, Figure, Link, Section, Table, Text, to_html, to_markdown
from hritest.rundir import RunDirectory, atomic_write

__all__ = ["RunData", "compare_runs", "load_run", "most_different", "worst_failures", "write_report"]

RECORDINGS = 10  # the worst failures recorded by default (the most different ones come on top)
SPLITS = 3  # blocks per measure when picking the most different failures
_BLOCK_NAMES = {2: ("low", "high"), 3: ("low", "mid", "high")}


@dataclass(frozen=True)
class RunData:
    """What a report needs from one run directory, read once."""

    path: Path
    meta: Mapping[str, Any]
    spec: Any  # hritest.spec.Spec
    records: Sequence[EvaluationRecord]
    progress: Sequence[Mapping[str, float]]
    elites: Sequence[EvaluationRecord]
    failures: Sequence[EvaluationRecord]  # the reported failures, worst first
    surrogate: Mapping[str, Any] | None

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def measure_names(self) -> list[str]:
        return [m.name for m in self.spec.measures]

    @property
    def ranges(self) -> list[tuple[float, float]]:
        return [tuple(m.range) for m in self.spec.measures]

    @property
    def labels(self) -> list[str]:
        """Theta's component names, as ``hritest show`` lists them."""
        labels = []
        for p in self.spec.parameters:
            labels += [p.name] if p.size == 1 else [f"{p.name}[{i}]" for i in range(p.size)]
        return labels


# --- reading ---------------------------------------------------------------------------------


def load_run(path: Path) -> RunData:
    """Reads a run directory.

    Raises:
        RunDirectoryError: not a run directory, or a corrupt one.
        EmptyRunError: no finished evaluation yet.
    """
    from hritest.replay import EmptyRunError, failure_ids
    from hritest.spec import load_spec

    run = RunDirectory.open(path)
    records = run.evaluations()
    if not records:
        raise EmptyRunError(
            f"{run.path} has no evaluations yet; there is nothing to report. "
            "Run 'hritest search --resume' on it, or start a new search"
        )
    spec = load_spec(run.path / "spec.yaml")
    by_index = {r.index: r for r in records}
    elite_ids = _elite_ids(run)
    surrogate = run.path / "surrogate.json"
    return RunData(
        path=run.path,
        meta=run.meta,
        spec=spec,
        records=records,
        progress=_read_progress(run.path / "progress.csv"),
        elites=[by_index[i] for i in elite_ids if i in by_index],
        failures=[by_index[i] for i in failure_ids(run, records) if i in by_index],
        surrogate=json.loads(surrogate.read_text()) if surrogate.is_file() else None,
    )


def _read_progress(path: Path) -> list[dict[str, float]]:
    if not path.is_file():
        return []
    with open(path, newline="") as handle:
        return [{k: float(v) for k, v in row.items() if v not in ("", None)} for row in csv.DictReader(handle)]


def _elite_ids(run: RunDirectory) -> list[int]:
    """The result archive's elites: ``archive.csv``, else the checkpoint's result archive."""
    path = run.path / "archive.csv"
    if path.is_file():
        with open(path, newline="") as handle:
            return [int(row["evaluation"]) for row in csv.DictReader(handle)]
    state = run.load_checkpoint()
    if state is None or "result" not in state:
        return []
    return [int(i) for i in state["result"].data("evaluation")]


# --- choosing what to show (pure) ------------------------------------------------------------


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


# --- recordings (I/O) ------------------------------------------------------------------------


@dataclass(frozen=True)
class Recorded:
    """A failure's recording and what its replay showed when it was made: ``matches`` says whether
    the re-simulation reproduced the stored outcome (None: not known, a recording left behind by
    ``hritest replay``); ``fresh`` whether it was made by this report rather than reused."""

    path: Path
    matches: bool | None
    differs: tuple[str, ...] = ()
    fresh: bool = False


REPLAYS = "replays.json"  # in recordings/: each recording's scenario digest and replay verdict


def record_failures(data: RunData, failures: Sequence[EvaluationRecord]) -> dict[int, Recorded]:
    """Re-simulates each failure (its stored raw theta and seed) into ``<run>/recordings/<id>.rrd``,
    unless a recording of that very scenario is there already (made by the search's own report, or
    an earlier one): recordings are made once per scenario."""
    from hritest.recording import check_writable, write_recording
    from hritest.replay import replay_record, run_domain, scenario_digest

    if not failures:
        return {}
    folder = data.path / "recordings"
    check_writable(folder / f"{failures[0].index}.rrd")
    known = _replays(folder)
    done, domain = {}, None
    for record in failures:
        path = folder / f"{record.index}.rrd"
        entry = known.get(str(record.index), {})
        digest = scenario_digest(data.meta["spec_digest"], record.theta_repaired, record.seed)
        if path.is_file() and entry.get("digest") == digest:
            done[record.index] = Recorded(path, entry.get("matches"), tuple(entry.get("differs", ())))
            continue
        domain = domain or run_domain(RunDirectory.open(data.path))
        replay = replay_record(domain, record, spec_digest=data.meta["spec_digest"])
        write_recording(
            path,
            domain=domain,
            evaluation=replay.evaluation,
            rollout=replay.rollout,
            recording_id=replay.digest,
            title=f"{data.spec.name}: failure {record.index} ({data.name})",
        )
        differs = tuple(c.name for c in replay.checks if not c.ok)
        done[record.index] = Recorded(path, replay.matches, differs, fresh=True)
        known[str(record.index)] = {"digest": digest, "matches": replay.matches, "differs": list(differs)}
    atomic_write(folder / REPLAYS, json.dumps(known, indent=1))
    return done


def _replays(folder: Path) -> dict[str, Any]:
    """The recordings' index; an unreadable one only means re-simulating (it is rewritten)."""
    try:
        data = json.loads((folder / REPLAYS).read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


# --- the report ------------------------------------------------------------------------------


def write_report(run_path: Path, *, recordings: int = RECORDINGS, out: Path | None = None) -> Path:
    """Writes the report of a run directory; returns the path of its ``index.html``.

    Args:
        run_path: the run directory.
        recordings: record this many worst failures plus the most different ones
            (0: record nothing, but link the recordings already there).
        out: the report folder (default ``<run>/report``).

    Raises:
        RunDirectoryError, EmptyRunError: not a readable run, or one with no evaluations.
        RecordingError: the recordings folder cannot be written.
    """
    data = load_run(run_path)
    out = Path(out) if out is not None else data.path / "report"
    out.mkdir(parents=True, exist_ok=True)
    recorded = record_failures(data, chosen_failures(data.failures, data.ranges, recordings))
    for r in data.failures:  # link what earlier reports or replays recorded
        earlier = data.path / "recordings" / f"{r.index}.rrd"
        if r.index not in recorded and earlier.is_file():
            recorded[r.index] = Recorded(earlier, None)
    doc = run_document(data, recorded, link_base=out, worst_count=max(recordings, RECORDINGS))
    _write(doc, out)
    return out / "index.html"


def compare_runs(run_paths: Sequence[Path], out: Path) -> Path:
    """One page that puts several runs on the same curves and their archives side by side.

    Raises:
        RunDirectoryError, EmptyRunError: any run that is not readable or has no evaluations.
    """
    runs = [load_run(p) for p in run_paths]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    _write(compare_document(runs, link_base=out), out)
    return out / "index.html"


def _write(doc: Document, out: Path) -> None:
    for figure in doc.figures():
        atomic_write(out / figure.name, figure.png)
    atomic_write(out / "summary.md", to_markdown(doc))
    atomic_write(out / "index.html", to_html(doc))


def run_document(
    data: RunData, recorded: Mapping[int, Recorded], *, link_base: Path, worst_count: int = RECORDINGS
) -> Document:
    """The report of one run as a document (no I/O: given the run and its recordings)."""
    spec = data.spec
    worst = worst_failures(data.failures, worst_count)
    diverse = most_different(data.failures, data.ranges)
    labelled = [r.index for _, r in diverse]  # one per block of the measure space: apart, so readable
    sections = [Section("The run at a glance", _glance(data))]
    archive_blocks: list = [
        Figure(
            "archive.png",
            figures.archive_heatmap(_view(data, labelled)),
            alt=f"result archive of {data.name}",
            caption=f"Best objective ({spec.objective.expr}) in each cell of the result "
            f"archive over {' and '.join(data.measure_names)}; grey cells are empty. Red "
            f"circles are failures ({spec.failure}); the numbered ones are the most "
            f"different failures, tabled below.",
        )
    ]
    sections.append(Section("Result archive", archive_blocks))
    sections.append(
        Section(
            "QD-score",
            [
                Figure(
                    "qd_score.png",
                    figures.qd_curves([(data.name, data.progress)]),
                    alt="QD-score curves",
                    caption="QD-score of the result archive after each batch, against evaluations and against the "
                    "search's wall time.",
                ),
                Details(
                    f"Progress log ({len(data.progress)} row{'s' * (len(data.progress) != 1)} of progress.csv)",
                    [_progress_table(data.progress)],
                ),
            ],
        )
    )
    if not data.failures:
        sections.append(
            Section(
                "Failures",
                [
                    Text(
                        f"No failures: no elite of the result archive meets the failure condition '{spec.failure}' "
                        f"after {len(data.records)} evaluations.",
                        note=True,
                    )
                ],
            )
        )
    else:
        sections.append(
            Section(
                f"Worst failures ({len(worst)} of {len(data.failures)})",
                [
                    _failure_table(data, [("", r) for r in worst], recorded, link_base),
                    Text(_replay_note(data, recorded)),
                ],
            )
        )
        sections.append(Section("Why they fail", _clause_blocks(data, recorded, link_base)))
        sections.append(
            Section(
                f"Most different failures ({len(diverse)} regions)",
                [
                    Text(
                        f"Each measure's range is cut into {SPLITS}; each row is the worst failure in one block of the "
                        f"measure space ({' / '.join(data.measure_names)})."
                    ),
                    _failure_table(data, diverse, recorded, link_base, label="region"),
                    Details(
                        f"All {len(data.failures)} failures, worst first",
                        [
                            _failure_table(
                                data,
                                [("", r) for r in worst_failures(data.failures, len(data.failures))],
                                recorded,
                                link_base,
                            )
                        ],
                    ),
                ],
            )
        )
    return Document(
        title=f"hritest report: {data.name}",
        subtitle=f"{spec.name}: {spec.description}".rstrip(": "),
        sections=sections,
    )


def _glance(data: RunData) -> list:
    spec, meta, last = data.spec, data.meta, (data.progress[-1] if data.progress else {})
    statuses = Counter(r.status.value for r in data.records)
    cells = 1
    for m in spec.measures:
        cells *= m.cells
    rows = [
        ("spec", f"{spec.name} ({meta.get('spec_file', 'spec.yaml')})"),
        ("spec digest", str(meta.get("spec_digest", ""))[:16]),
        (
            "algorithm",
            f"{meta.get('algorithm', '?')}, seed {meta.get('seed', '?')}"
            + (f", {meta['inner_iterations']:,} inner iterations" if "inner_iterations" in meta else ""),
        ),
        ("evaluations", f"{len(data.records)} of a budget of {meta.get('budget', '?')}"),
        ("statuses", ", ".join(f"{n} {s}" for s, n in sorted(statuses.items()))),
        ("wall time", f"{last['wall_time']:.1f} s" if "wall_time" in last else "not recorded"),
        ("QD-score", f"{last['qd_score']:.2f}" if "qd_score" in last else "not recorded"),
        (
            "QD-score, normalised",
            f"{last['normalized_qd_score']:.4f}" if "normalized_qd_score" in last else "not recorded",
        ),
        ("coverage", f"{last['coverage']:.2%} of {cells} cells" if "coverage" in last else "not recorded"),
        ("best objective", f"{max((r.objective for r in data.elites), default=float('nan')):.4g}"),
        ("failures", f"{len(data.failures)} elites meet '{spec.failure}'"),
        ("started", str(meta.get("created", "?"))),
    ]
    blocks: list = [Table(["", ""], [[k, v] for k, v in rows])]
    if data.surrogate is not None:
        overall = {k: v for k, v in data.surrogate.items() if k not in ("per_outer_iteration", "fits")}
        blocks.append(
            Table(
                ["surrogate", "value"],
                [[k, v] for k, v in _flatten(overall)],
                caption="Surrogate accuracy on the proposals it made, before they were simulated (surrogate.json)",
            )
        )
        per_outer = data.surrogate.get("per_outer_iteration", [])
        if per_outer:
            columns = ["outer_iteration", "held_out", "objective_mae", "right_cell_fraction", "mean_cell_distance"]
            blocks.append(
                Table(
                    columns,
                    [[_format(row[c]) for c in columns] for row in per_outer],
                    caption="The same, per outer iteration",
                )
            )
    return blocks


def _flatten(value: Any, prefix: str = "") -> list[tuple[str, str]]:
    if isinstance(value, Mapping):
        rows = []
        for k, v in value.items():
            rows += _flatten(v, f"{prefix}.{k}" if prefix else str(k))
        return rows
    return [(prefix, _format(value))]


def _format(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return json.dumps(value) if isinstance(value, (list, dict)) else str(value)


def _view(data: RunData, labelled: Sequence[int], title: str | None = None) -> figures.ArchiveView:
    spec = data.spec
    return figures.ArchiveView(
        title=title or f"{data.name}: {len(data.elites)} elites, {len(data.failures)} failures",
        measure_names=data.measure_names,
        ranges=data.ranges,
        cells=[m.cells for m in spec.measures],
        objective_range=tuple(spec.objective.range),
        objective_label=f"objective: {spec.objective.expr}",
        elites=[(r.objective, list(r.measures)) for r in data.elites],
        failures=[(r.index, list(r.measures)) for r in data.failures],
        labelled=labelled,
    )


def _progress_table(progress: Sequence[Mapping[str, float]]) -> Table:
    columns = ["evaluations", "wall_time", "qd_score", "normalized_qd_score", "coverage", "best", "failures"]
    return Table(columns, [[_num(row.get(c)) for c in columns] for row in progress])


def _num(value: float | None) -> str:
    if value is None:
        return "—"
    return str(int(value)) if float(value).is_integer() and abs(value) < 1e12 else f"{value:.6g}"


def _failure_table(
    data: RunData,
    rows: Sequence[tuple[str, EvaluationRecord]],
    recorded: Mapping[int, Recorded],
    link_base: Path,
    *,
    label: str | None = None,
) -> Table:
    """A row per failure; with ``label``, a first column of that name holds each row's label."""
    headers = ([label] if label else []) + [
        "id",
        "objective",
        "why (clauses that held)",
        *data.measure_names,
        "repair cost",
        "seed",
        "scenario parameters (repaired theta)",
        "recording",
    ]
    labels = data.labels
    table_rows = []
    for block, r in rows:
        theta = ", ".join(f"{k} {v:.4g}" for k, v in zip(labels, r.theta_repaired))
        found = recorded.get(r.index)
        if found is None:
            recording: Any = "not recorded"
        else:
            link = Link(f"{r.index}.rrd", os.path.relpath(found.path, link_base))
            recording = (
                link
                if found.matches is not False
                else Badge(f"{link.text}: replay differs in {', '.join(found.differs)}", False)
            )
        table_rows.append(
            [
                *([block] if label else []),
                str(r.index),
                _fmt(r.objective),
                clauses_text(r.fired) if r.clauses else "not recorded",
                *(_fmt(v) for v in r.measures),
                _fmt(r.repair_cost),
                str(r.seed),
                Code(theta),
                recording,
            ]
        )
    return Table(headers, table_rows)


def _fmt(value: float) -> str:
    return f"{value:.4g}" if math.isfinite(value) else "—"


def _clause_blocks(data: RunData, recorded: Mapping[int, Recorded], link_base: Path) -> list:
    """Each clause of the failure condition: in how many failures it held, and the worst of them."""
    from hritest.spec import expr

    clauses = [c.text for c in expr.parse(data.spec.failure, condition=True).clauses()]
    if not any(r.clauses for r in data.failures):
        return [
            Text(
                "This run's evaluations do not record which clause of the failure condition held (a run directory "
                "written before hritest recorded clauses); replay a failure to see them.",
                note=True,
            )
        ]
    counts = Counter(c.text for r in data.failures for c in r.fired)
    worst = worst_of_each_clause(rank_failures(data.failures))
    table = Table(
        ["clause of the failure condition", "failures where it held"],
        [[Code(c), f"{counts[c]} of {len(data.failures)}"] for c in clauses],
        caption=f"The failure condition '{data.spec.failure}', clause by clause. A failure may meet several.",
    )
    rows = [(clause, worst[clause]) for clause in clauses if clause in worst]
    return [
        table,
        Text("The worst failure of each clause that held:"),
        _failure_table(data, rows, recorded, link_base, label="clause"),
    ]


def _replay_note(data: RunData, recorded: Mapping[int, Recorded]) -> str:
    replayed = {i: r for i, r in recorded.items() if r.matches is not None}
    if not replayed:
        return (
            "No failure was re-simulated for this report (--recordings 0); links go to recordings made "
            f"earlier, if any. Make one with 'hritest replay {data.path} --failure ID'."
        )
    differ = sorted(i for i, r in replayed.items() if not r.matches)
    verdict = (
        "each re-simulation reproduced its stored outcome (status, failure verdict, objective and measures within 1e-6)"
        if not differ
        else f"the re-simulations of failures {differ} did NOT reproduce their stored outcome"
    )
    fresh = sum(r.fresh for r in replayed.values())
    when = "now" if fresh == len(replayed) else f"{fresh} now, the others by an earlier report of this run"
    return (
        f"{len(replayed)} failures were re-simulated from their stored raw theta and seed ({when}) and recorded "
        f"for Rerun under recordings/; {verdict}. Open one with 'rerun FILE.rrd', or "
        f"'hritest replay {data.path} --failure ID --open'."
    )


# --- comparing runs --------------------------------------------------------------------------


def compare_document(runs: Sequence[RunData], *, link_base: Path) -> Document:
    """Several runs on one page: a table, shared QD-score curves, the archives side by side."""
    labels = _run_labels(runs)
    same_spec = len({r.meta.get("spec_digest") for r in runs}) == 1
    rows = []
    for name, get in (
        ("spec", lambda d: d.spec.name),
        ("algorithm", lambda d: f"{d.meta.get('algorithm', '?')}, seed {d.meta.get('seed', '?')}"),
        ("evaluations", lambda d: str(len(d.records))),
        ("wall time", lambda d: f"{d.progress[-1]['wall_time']:.1f} s" if d.progress else "—"),
        ("QD-score", lambda d: f"{d.progress[-1]['qd_score']:.2f}" if d.progress else "—"),
        ("QD-score, normalised", lambda d: f"{d.progress[-1]['normalized_qd_score']:.4f}" if d.progress else "—"),
        ("coverage", lambda d: f"{d.progress[-1]['coverage']:.2%}" if d.progress else "—"),
        ("failures", lambda d: str(len(d.failures))),
    ):
        rows.append([name, *(get(d) for d in runs)])
    reports = []
    for label, d in zip(labels, runs):
        page = d.path / "report" / "index.html"
        reports.append(
            Link(label, os.path.relpath(page, link_base))
            if page.is_file()
            else f"{label}: no report yet (hritest report {d.path})"
        )
    rows.append(["report", *reports])
    curves = figures.qd_curves([(label, d.progress) for label, d in zip(labels, runs)], normalised=not same_spec)
    heatmaps = figures.archive_heatmaps(
        [_view(d, [], title=f"{label}: {len(d.failures)} failures") for label, d in zip(labels, runs)]
    )
    note = (
        []
        if same_spec
        else [
            Text(
                "These runs come from different specs, so the curves show the normalised "
                "QD-score (QD-score / (cells x objective range)).",
                note=True,
            )
        ]
    )
    return Document(
        title=f"hritest comparison of {len(runs)} runs",
        subtitle=", ".join(labels),
        sections=[
            Section("The runs at a glance", [Table(["", *labels], rows)]),
            Section("QD-score", [*note, Figure("qd_score.png", curves, alt="QD-score curves of every run")]),
            Section(
                "Result archives",
                [
                    Figure(
                        "archives.png",
                        heatmaps,
                        alt="result archives side by side",
                        caption="Best objective per cell (grey: empty); red circles are failures.",
                    )
                ],
            ),
        ],
    )


def _run_labels(runs: Sequence[RunData]) -> list[str]:
    names = [r.name for r in runs]
    if len(set(names)) == len(names):
        return names
    return [f"{r.path.parent.name}/{r.name}" if names.count(r.name) > 1 else r.name for r in runs]
