"""Reading a run directory once, for a report: its records, progress, elites and failures."""

from __future__ import annotations

import csv
import json
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hritest.records import EvaluationRecord
from hritest.report.clusters import Cluster, cluster_failures
from hritest.rundir import RunDirectory


@dataclass(frozen=True)
class RunData:
    """What a report needs from one run directory, read once."""

    path: Path
    meta: Mapping[str, Any]
    spec: Any  # hritest.spec.Spec
    evaluated: int  # committed evaluations
    statuses: Mapping[str, int]  # how many of them ended with each status
    progress: Sequence[Mapping[str, float]]
    elites: Sequence[EvaluationRecord]
    failures: Sequence[EvaluationRecord]  # the reported failures, worst first
    clusters: Sequence[Cluster]  # the kinds of failure, largest first
    surrogate: Mapping[str, Any] | None
    auto: Mapping[str, Any] | None = None  # auto.json: where --algorithm auto spent the time, and why
    shrunk: Mapping[int, Mapping[str, Any]] = field(default_factory=dict)  # RUN/shrunk/ID.json, by id
    trust: bool = False  # the user vouches for the run: its plugin files load though another user wrote it

    def domain(self) -> Any:  # hritest.domain.Domain
        """The run's spec compiled, to re-simulate its scenarios (see :func:`hritest.replay.run_domain`).

        Raises:
            RunDirectoryError: plugin files from outside the user's project in a run another user
                wrote, unless ``trust``.
        """
        from hritest.replay import run_domain

        return run_domain(RunDirectory.open(self.path), trust=self.trust)

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


def load_run(path: Path, *, trust: bool = False) -> RunData:
    """Reads a run directory; ``trust`` loads its checkpoint and plugin files though another user
    wrote them (see :mod:`hritest.rundir`).

    Raises:
        RunDirectoryError: not a run directory, a corrupt one, or a checkpoint this user did not
            write (unless ``trust``).
        EmptyRunError: no finished evaluation yet.
    """
    from hritest.replay import EmptyRunError, failure_ids
    from hritest.spec import load_spec

    run = RunDirectory.open(path)
    if not run.has_evaluations():
        raise EmptyRunError(
            f"{run.path} has no evaluations yet; there is nothing to report. "
            "Run 'hritest search --resume' on it, or start a new search"
        )
    spec = load_spec(run.path / "spec.yaml")
    elite_ids, reported = _elite_ids(run, trust=trust), failure_ids(run)
    # One pass over the records, keeping only those shown: a million of them take gigabytes.
    wanted, by_index, statuses = {*elite_ids, *reported}, {}, Counter()
    for record in run.iter_evaluations():
        statuses[record.status.value] += 1
        if record.index in wanted:
            by_index[record.index] = record
    surrogate, auto = run.path / "surrogate.json", run.path / "auto.json"
    failures = [by_index[i] for i in reported if i in by_index]
    clusters = cluster_failures(
        failures,
        measure_names=[m.name for m in spec.measures],
        ranges=[tuple(m.range) for m in spec.measures],
        seed=int(run.meta.get("seed", 0)),
    )
    return RunData(
        path=run.path,
        meta=run.meta,
        spec=spec,
        evaluated=sum(statuses.values()),
        statuses=dict(statuses),
        progress=_read_progress(run.path / "progress.csv"),
        elites=[by_index[i] for i in elite_ids if i in by_index],
        failures=failures,
        clusters=clusters,
        surrogate=json.loads(surrogate.read_text()) if surrogate.is_file() else None,
        auto=json.loads(auto.read_text()) if auto.is_file() else None,
        shrunk=_shrunk(run.path / "shrunk"),
        trust=trust,
    )


def _shrunk(folder: Path) -> dict[int, dict[str, Any]]:
    """What ``hritest shrink`` stored; a file that does not read is left out (shrink it again)."""
    found = {}
    for path in sorted(folder.glob("*.json")) if folder.is_dir() else ():
        try:
            found[int(path.stem)] = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
    return found


def _read_progress(path: Path) -> list[dict[str, float | str]]:
    """``progress.csv``'s rows: numbers, and the name of what proposed each batch."""
    if not path.is_file():
        return []
    with open(path, newline="") as handle:
        return [
            {k: v if k == "proposer" else float(v) for k, v in row.items() if v not in ("", None)}
            for row in csv.DictReader(handle)
        ]


def _elite_ids(run: RunDirectory, *, trust: bool) -> list[int]:
    """The result archive's elites: ``archive.csv``, else the checkpoint's result archive."""
    path = run.path / "archive.csv"
    if path.is_file():
        with open(path, newline="") as handle:
            return [int(row["evaluation"]) for row in csv.DictReader(handle)]
    from hritest.search.state import load_state

    state = load_state(run, trust=trust)  # verified as this user's before it is unpickled, unless trusted
    return [] if state is None else [int(i) for i in state.result.data("evaluation")]
