"""The report of one run, and the comparison of several, as documents (no I/O)."""

from __future__ import annotations

import json
import math
import os
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from hritest.records import EvaluationRecord, clauses_text, rank_failures, worst_of_each_clause
from hritest.report import figures
from hritest.report.contrast import Contrast
from hritest.report.html import Badge, Code, Details, Document, Figure, Link, Section, Table, Text
from hritest.report.recordings import Recorded
from hritest.report.run import RunData
from hritest.report.select import worst_failures
from hritest.search.archives import tessellation

RECORDINGS = 10  # the worst failures recorded by default (the most different ones come on top)


def run_document(
    data: RunData,
    recorded: Mapping[int, Recorded],
    *,
    link_base: Path,
    worst_count: int = RECORDINGS,
    contrast: Contrast | None = None,
) -> Document:
    """The report of one run as a document (no I/O: given the run, its recordings and the first
    kind's counterfactual)."""
    spec = data.spec
    worst = worst_failures(data.failures, worst_count)
    labelled = [c.representative.index for c in data.clusters]
    sections = [Section("The run at a glance", _glance(data))]
    archive_blocks: list = [
        Figure(
            "archive.png",
            figures.archive_heatmap(_view(data, labelled)),
            alt=f"result archive of {data.name}",
            caption=f"Best objective ({spec.objective.expr}) in each cell of the result "
            f"archive over {' and '.join(data.measure_names)}; grey cells are empty. Circles "
            f"are failures ({spec.failure}), coloured by kind; the numbered ones are each "
            f"kind's representative, tabled below.",
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
                        f"after {data.evaluated} evaluations.",
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
        if contrast is not None:
            sections.append(Section("What would have passed", _contrast_blocks(data, contrast, link_base)))
        sections.append(
            Section(
                f"Kinds of failure ({len(data.clusters)})",
                [
                    Text(
                        "The failures clustered by how they behaved (measures, objective, every metric the task "
                        "reports, and which clauses held). Each kind is represented by its worst failure."
                    ),
                    Table(
                        ["kind", "failures", "what sets it apart", "representative", "what it needs (shrunk)"],
                        [
                            [
                                str(i + 1),
                                str(len(c.members)),
                                "; ".join(c.traits) or "—",
                                str(c.representative.index),
                                _needs(data, c.representative.index),
                            ]
                            for i, c in enumerate(data.clusters)
                        ],
                    ),
                    _failure_table(
                        data,
                        [(f"kind {i + 1}", c.representative) for i, c in enumerate(data.clusters)],
                        recorded,
                        link_base,
                        label="kind",
                    ),
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
    cells = spec.archive.cells if spec.archive.type == "cvt" else math.prod(m.cells for m in spec.measures)
    rows = [
        ("spec", f"{spec.name} ({meta.get('spec_file', 'spec.yaml')})"),
        ("spec digest", str(meta.get("spec_digest", ""))[:16]),
        (
            "algorithm",
            f"{meta.get('algorithm', '?')}, seed {meta.get('seed', '?')}"
            + (f", {meta['inner_iterations']:,} inner iterations" if "inner_iterations" in meta else ""),
        ),
        ("evaluations", f"{data.evaluated} {_limits(meta)}"),
        ("statuses", ", ".join(f"{n} {s}" for s, n in sorted(data.statuses.items()))),
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
    if data.auto is not None:
        columns = ["stints", "evaluations", "seconds", "time_share", "qd_score_gained", "recent_rate", "score"]
        blocks.append(
            Table(
                ["auto: arm", *columns],
                [[arm, *(_format(row.get(c, "")) for c in columns)] for arm, row in data.auto["arms"].items()],
                caption="Where --algorithm auto spent the time: each stint of a few seconds goes to the arm "
                "with the best recent score (its QD-score per second over the search's pace just before), "
                "a losing arm is measured again now and then, in at most 8% of the run; every choice and "
                "its measurements are in auto.json",
            )
        )
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
        centroids=(
            tessellation(spec.archive.cells, tuple(map(tuple, data.ranges)), spec.archive.samples)
            if spec.archive.type == "cvt"
            else None
        ),
        objective_range=tuple(spec.objective.range),
        objective_label=f"objective: {spec.objective.expr}",
        elites=[(r.objective, list(r.measures)) for r in data.elites],
        failures=[(r.index, list(r.measures)) for r in data.failures],
        labelled=labelled,
        kinds={r.index: i + 1 for i, c in enumerate(data.clusters) for r in c.members},
    )


def _limits(meta: Mapping) -> str:
    """``of a budget of 500, in at most 15 min; stopped at the time limit``."""
    budget, limit, stopped = meta.get("budget", "?"), meta.get("time_limit"), meta.get("stopped")
    text = "with no evaluation budget" if budget is None else f"of a budget of {budget}"
    if limit is not None:
        text += f", a time limit of {limit:g} s per session"
    return text + (f"; stopped at its {stopped}" if stopped else "")


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


def _needs(data: RunData, index: int) -> str:
    """The parameters a shrunk failure still needs away from nominal, or how to find them."""
    shrunk = data.shrunk.get(index)
    if shrunk is None or shrunk.get("seed") != next((r.seed for r in data.failures if r.index == index), None):
        return f"hritest shrink {data.path} --failure {index}"
    needed = [name for name, row in shrunk.get("parameters", {}).items() if row.get("matters")]
    what = ", ".join(needed) or "nothing: the nominal scenario fails too"
    return f"{what} ({shrunk.get('evaluations', '?')} simulations)"


def _contrast_blocks(data: RunData, contrast: Contrast, link_base: Path) -> list:
    """The first kind's representative beside the nearest passing scenario found."""
    failure, passing = contrast.failure, contrast.passing
    if passing is None:
        return [Text(f"No passing scenario near failure {failure.index}: {contrast.reason}.", note=True)]
    changed = ", ".join(contrast.changed)
    intro = Text(
        f"Failure {failure.index}, the representative of the largest kind, beside the nearest passing scenario "
        f"a {contrast.evaluations}-simulation search found (same seed): changing {changed} "
        f"(a distance of {contrast.distance:.3g} in theta scaled by the bounds) makes it pass."
    )
    labels = data.labels
    parameters = Table(
        ["parameter", "failure", "passing", "change"],
        [
            [label, _fmt(a), _fmt(b), _fmt(b - a) if abs(b - a) > 1e-12 else ""]
            for label, a, b in zip(labels, failure.theta_repaired, passing["theta_repaired"])
        ],
        caption="Scenario parameters (repaired theta)",
    )
    rows = [["objective", _fmt(failure.objective), _fmt(passing["objective"])]]
    rows += [[m, _fmt(a), _fmt(b)] for m, a, b in zip(data.measure_names, failure.measures, passing["measures"])]
    rows += [[k, _fmt(v), _fmt(passing["metrics"].get(k, math.nan))] for k, v in failure.metrics.items()]
    outcome = Table(["", "failure", "passing"], rows, caption="Outcome and every metric")
    blocks = [intro, parameters, outcome]
    if contrast.recording is not None:
        link = Link(contrast.recording.name, os.path.relpath(contrast.recording, link_base))
        blocks.append(Table(["both episodes, side by side on one timeline (Rerun)"], [[link]]))
    return blocks


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
        ("evaluations", lambda d: str(d.evaluated)),
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
