"""Promoting a run's failures into the failure corpus (``hritest promote``): which failures,
in what order, and the entry each becomes (:mod:`hritest.corpus` holds the entries' format)."""

from __future__ import annotations

import json
import os
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from hritest.corpus import FORMAT, CorpusError, dump_entry, load_entry


@dataclass(frozen=True)
class Promoted:
    """One failure of a run and where it stands in the corpus."""

    path: Path
    evaluation: int
    objective: float
    added: bool  # False: the corpus already held it (its status is left as it was)
    upgraded: bool = False  # it held it in an older format: rewritten in this one, its status kept


def promote(run_path: Path, *, corpus: Path, top: int | None = None, shrink: bool = False) -> list[Promoted]:
    """Copies ``top`` failures of a run (all by default) into the corpus: the worst failure of each
    clause of the failure condition that fired, then the worst of the rest (:func:`chosen`). With
    ``shrink``, each is first shrunk (:mod:`hritest.shrink`, or read back from ``RUN/shrunk/``)
    and its simplest version is kept instead.

    Idempotent: a failure already in the corpus (same scenario digest) is left untouched, unless it was
    written in an older format: then it is rewritten in this one (with an outcome digest), its status kept.

    Raises:
        RunDirectoryError: not a run directory.
        CorpusError: the spec changed since the run, or the corpus folder cannot be written.
    """
    from hritest import replay
    from hritest.outcome_digest import outcome_digest
    from hritest.records import scenario_digest
    from hritest.rundir import RunDirectory, atomic_write, digest

    run = RunDirectory.open(run_path)
    spec_file = Path(run.meta["spec_file"])
    spec_digest = run.meta["spec_digest"]
    if not spec_file.is_file():
        raise CorpusError(
            f"{spec_file} (the spec of {run.path}) no longer exists; a corpus entry must point "
            "at the spec it replays with"
        )
    if digest(spec_file) != spec_digest:
        raise CorpusError(
            f"{spec_file} changed since the run {run.path} started, so its failures would be "
            "stale at once; run a new search with the current spec and promote from that"
        )
    reported = replay.failure_ids(run)
    records = run.evaluations_of(reported)
    ids = chosen([records[i] for i in reported if i in records], top)
    if not ids:
        return []
    domain = replay.run_domain(run)
    if shrink:
        records |= {i: _shrunk(run, domain, records[i]) for i in ids}
    outcome = outcome_digest(domain)
    labels = domain.space.labels
    folder = Path(corpus) / domain.spec.name
    _writable(folder)
    scenarios = {i: scenario_digest(spec_digest, records[i].theta_repaired, records[i].seed) for i in ids}
    # every entry already there is read before any is written: a malformed one changes nothing
    held = {i: load_entry(p) for i in ids if (p := folder / f"{scenarios[i][:12]}.yaml").exists()}
    done = []
    for index in ids:
        record, scenario, old = records[index], scenarios[index], held.get(index)
        path = folder / f"{scenario[:12]}.yaml"
        added = old is None
        upgraded = old is not None and old.format < FORMAT
        if added or upgraded:
            data = {
                "format": FORMAT,
                "status": "open" if old is None else old.status,
                "spec": os.path.relpath(spec_file.resolve(), folder.resolve()),
                "spec_name": domain.spec.name,
                "spec_digest": spec_digest,
                "outcome_digest": outcome.digest,
                "outcome_parts": dict(outcome.parts),
                "failure_condition": domain.spec.failure,
                "seed": record.seed,
                "seconds": round(record.seconds, 3),
                "objective": record.objective,
                "why": [str(c) for c in record.fired],
                "measures": {m.name: v for m, v in zip(domain.measures, record.measures)},
                "theta": dict(zip(labels, record.theta)),
                "theta_repaired": dict(zip(labels, record.theta_repaired)),
                "metrics": dict(record.metrics),
                "scenario_digest": scenario,
                "versions": {
                    k: v
                    for k, v in run.meta.get("versions", {}).items()
                    if k in ("hritest", "mujoco", "python", "machine")
                },
                "origin": {
                    "run": str(run.path.resolve()),
                    "evaluation": index,
                    "shrunk": shrink,
                    "promoted": datetime.now(UTC).isoformat(timespec="seconds"),
                },
            }
            atomic_write(path, dump_entry(data))
        done.append(Promoted(path=path, evaluation=index, objective=record.objective, added=added, upgraded=upgraded))
    return done


def _shrunk(run: Any, domain: Any, record: Any) -> Any:
    """The shrunk version of a failure's record: RUN/shrunk/ID.json when it holds this failure's
    seed, else shrunk now (which writes it); simulated once more for its full record."""
    from hritest.evaluate import evaluate
    from hritest.records import EvaluationRecord
    from hritest.shrink import shrink_failure

    path = run.path / "shrunk" / f"{record.index}.json"
    try:
        stored = json.loads(path.read_text())
    except (OSError, ValueError):
        stored = {}
    if stored.get("seed") != record.seed or len(stored.get("theta", ())) != len(record.theta):
        result, _ = shrink_failure(run.path, record.index)
        stored = {"theta": result.theta.tolist()}
    evaluation = evaluate(domain, stored["theta"], seed=record.seed)
    if not (evaluation.ok and evaluation.failure):
        raise CorpusError(f"{path}: the shrunk scenario of failure {record.index} no longer fails; shrink it again")
    return EvaluationRecord.of(evaluation, index=record.index, batch=record.batch)


def new_failures(found: Any, held: Collection[str]) -> list[str]:
    """The failures of a finished search (a :class:`hritest.search.Search`) whose scenario digest is not
    in ``held``, one line each: its id in the corpus, objective, measures and the clauses that held."""
    from hritest.records import scenario_digest

    spec_digest = found.run_dir.meta["spec_digest"]
    names = [m.name for m in found.domain.measures]
    lines = []
    for record in found.failures():
        scenario = scenario_digest(spec_digest, record.theta_repaired, record.seed)
        if scenario not in held:
            measures = "  ".join(f"{n} {v:.4g}" for n, v in zip(names, record.measures))
            why = "; ".join(map(str, record.fired))
            lines.append(f"  {scenario[:12]}  objective {record.objective:.6g}  {measures}  fails {why}")
    return lines


def chosen(failures: Sequence[Any], top: int | None) -> list[int]:
    """The ids of ``top`` failures (all when None): the worst of each failure clause that fired first,
    so that a safety clause with low objectives is kept too, then the rest in the one failure ranking
    (:func:`hritest.records.rank_failures`)."""
    from hritest.records import rank_failures, worst_of_each_clause

    ranked = rank_failures(failures)
    order = list(dict.fromkeys([r.index for r in worst_of_each_clause(ranked).values()] + [r.index for r in ranked]))
    return order if top is None else order[:top]


def _writable(folder: Path) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CorpusError(
            f"cannot create the corpus folder {folder} ({exc.strerror}); choose another with --to"
        ) from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise CorpusError(f"the corpus folder {folder} is not writable; choose another with --to")
