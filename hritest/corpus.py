"""The failure corpus: failures kept in the user's repository as small YAML files, replayed by pytest.

Layout: ``<corpus>/<spec name>/<scenario digest[:12]>.yaml``, one file per failure::

    # hritest failure corpus entry (replayed by pytest). Change `status` by hand or with
    # `hritest promote --mark-fixed ID`; edit nothing else.
    format: 2
    status: open                # open: still a failure (xfail); fixed: must not fail (regression)
    spec: ../../../specs/teleop.yaml   # relative to this file
    spec_name: teleop
    spec_digest: 4d3d387f...    # sha256 of the spec file's bytes when it was recorded
    outcome_digest: 9b1e22c0... # what decides the outcome (hritest.outcome_digest), and its parts:
    outcome_parts: {scenario space: 51c0..., task plugin source: 0e4f..., failure condition: 77aa..., ...}
    failure_condition: objective >= 10
    seed: 3344922676
    seconds: 0.41               # how long its evaluation took (the default replay timeout grows with it)
    objective: 10.0
    why: ['objective >= 10 (objective=10)']   # the failure condition's clauses that held
    measures: {goal_distance: 0.045, variation: 0.077}
    theta: {g0x: 0.588, ...}          # raw, as the search proposed it (what a replay evaluates)
    theta_repaired: {g0x: 0.588, ...}
    metrics: {completion_time: 10.0, ...}
    scenario_digest: 3f2a9c1b4d5e...  # sha256 of spec digest, repaired theta and seed
    versions: {hritest: 0.1.0, mujoco: 4.0.0, ...}
    origin: {run: /abs/runs/teleop-..., evaluation: 33, promoted: '2026-...'}

Format 1 files (no outcome digest, no ``why``, no ``seconds``) still load and replay.

This module reads and writes entries with the standard library and PyYAML only, so that the
pytest plugin can collect a corpus without importing the simulator; :func:`promote` (the CLI's)
imports the heavy modules when it runs.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Collection, Sequence
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hritest.errors import HritestError

if TYPE_CHECKING:
    from hritest.replay import Replay

FORMAT = 2
FORMATS = (1, 2)  # the formats this hritest reads
SUFFIX = ".yaml"
DEFAULT_CORPUS = Path("tests") / "hri_failures"
STATUSES = ("open", "fixed")
HEADER = (
    "# hritest failure corpus entry (replayed by pytest). Change `status` by hand or with\n"
    "# `hritest promote --mark-fixed ID`; edit nothing else.\n"
)
_HEX64 = re.compile(r"[0-9a-f]{64}")


class CorpusError(HritestError):
    """A corpus entry that cannot be read or written, naming the file and the field."""


@dataclass(frozen=True, kw_only=True)
class Entry:
    """One corpus file, validated. ``theta`` and ``theta_repaired`` map labels to values in order.

    ``id`` is the file's name without ``.yaml`` (the scenario digest's first 12 hex digits).
    """

    path: Path
    id: str
    status: str
    spec: str
    spec_name: str
    spec_digest: str
    seed: int
    objective: float
    measures: dict[str, float]
    theta: dict[str, float]
    theta_repaired: dict[str, float]
    metrics: dict[str, float | None]
    scenario_digest: str
    failure_condition: str = ""
    format: int = FORMAT
    outcome_digest: str = ""  # empty in format 1
    outcome_parts: dict[str, str] | None = None
    why: tuple[str, ...] = ()  # the clauses that held when it was recorded
    seconds: float | None = None
    versions: dict[str, Any] | None = None
    origin: dict[str, Any] | None = None

    @property
    def spec_path(self) -> Path:
        """The spec file, resolved against this entry's folder."""
        return (self.path.parent / self.spec).resolve()


# --- locating the corpus -----------------------------------------------------------------------


def default_corpus(start: Path) -> Path:
    """The corpus folder for a project at or above ``start``.

    The nearest ``pyproject.toml`` at or above ``start`` decides: its ``[tool.hritest] corpus``
    (relative to that file), else ``tests/hri_failures`` beside it. Without one, ``start/tests/hri_failures``.
    """
    start = Path(start).resolve()
    for folder in (start, *start.parents):
        pyproject = folder / "pyproject.toml"
        if pyproject.is_file():
            configured = _configured_corpus(pyproject)
            return folder / (configured if configured is not None else DEFAULT_CORPUS)
    return start / DEFAULT_CORPUS


def _configured_corpus(pyproject: Path) -> str | None:
    import tomllib

    try:
        data = tomllib.loads(pyproject.read_text())
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError):
        return None  # not ours to judge; pip or pytest will complain about a broken pyproject.toml
    value = data.get("tool", {}).get("hritest", {}).get("corpus")
    if value is not None and not isinstance(value, str):
        raise CorpusError(
            f"{pyproject}: [tool.hritest] corpus must be a folder path (a string), "
            f"got {value!r} ({type(value).__name__})"
        )
    return value


def entry_files(corpus: Path) -> list[Path]:
    """Every entry file of the corpus (``<spec>/<id>.yaml``), sorted."""
    corpus = Path(corpus)
    return sorted(corpus.glob(f"*/*{SUFFIX}")) if corpus.is_dir() else []


def is_entry(path: Path) -> bool:
    """Whether a YAML file is a corpus entry rather than a spec: it has a top-level ``scenario_digest``
    field (looked for in the text, so that nothing is parsed)."""
    try:
        return re.search(r"^scenario_digest:", Path(path).read_text(errors="replace"), re.MULTILINE) is not None
    except OSError:
        return False


def misplaced(corpus: Path, path: Path) -> str:
    """Why a YAML file under ``corpus`` is not where an entry lives (``<corpus>/<spec>/<id>.yaml``), or ``""``.

    A file that looks like an entry but would not be replayed is an error, never silently ignored.
    """
    path, corpus = Path(path).resolve(), Path(corpus).resolve()
    if path.suffix == ".yml":
        return f"{path}: corpus entries are named <id>.yaml; rename it to {path.with_suffix(SUFFIX).name}"
    if path.parent == corpus:
        return (
            f"{path}: corpus entries live in a folder per spec, <corpus>/<spec name>/<id>.yaml; move it into "
            f"{corpus}/<its spec_name>/"
        )
    if path.parent.parent != corpus:
        return f"{path}: corpus entries live at <corpus>/<spec name>/<id>.yaml, one folder deep; move it to {corpus}/"
    return ""


# --- reading -----------------------------------------------------------------------------------


def load_entry(path: Path) -> Entry:
    """Reads and validates one corpus file.

    Raises:
        CorpusError: unreadable YAML, a missing field, or a field of the wrong type; the message
            names the file and the field.
    """
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise CorpusError(f"{path}: cannot be read ({exc.strerror})") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f":{mark.line + 1}:{mark.column + 1}" if mark else ""
        raise CorpusError(f"{path}{where}: not valid YAML ({getattr(exc, 'problem', None) or exc})") from None
    if not isinstance(data, dict):
        raise CorpusError(f"{path}: a corpus entry is a YAML mapping of fields, got {type(data).__name__}")
    field = _Fields(path, data)
    version = data.get("format", 1)
    if version not in FORMATS:
        raise field.bad("format", f"this hritest reads corpus formats {', '.join(map(str, FORMATS))}")
    status = field.text("status")
    if status not in STATUSES:
        raise field.bad("status", "must be 'open' or 'fixed'")
    digest = field.text("spec_digest")
    if not _HEX64.fullmatch(digest):
        raise field.bad("spec_digest", "must be the 64-hex-digit sha256 of the spec file")
    theta = field.numbers("theta")
    repaired = field.numbers("theta_repaired")
    if list(theta) != list(repaired):
        raise field.bad("theta_repaired", f"must have the same labels as theta ({', '.join(theta)})")
    seed = field.integer("seed")
    scenario = field.text("scenario_digest")
    from hritest.records import scenario_digest  # here: collecting the corpus imports no more than it needs

    if scenario != scenario_digest(digest, repaired.values(), seed):
        raise field.bad(
            "scenario_digest",
            "does not match the fields 'spec_digest', 'theta_repaired' and 'seed': one of them was edited; "
            "restore the file from version control, or promote the failure again",
        )
    if not scenario.startswith(path.stem):
        raise field.bad("scenario_digest", f"must start with the file's name ({path.stem}); was the file renamed?")
    outcome_parts = field.mapping("outcome_parts") if version >= 2 else None
    if version >= 2 and not outcome_parts:
        raise field.bad("outcome_parts", "must be a mapping of outcome parts to digests (format 2)")
    why = data.get("why") or []
    if not isinstance(why, list) or not all(isinstance(w, str) for w in why):
        raise field.bad("why", "must be a list of the clauses that held, as text")
    return Entry(
        path=path,
        id=path.stem,
        status=status,
        spec=field.text("spec"),
        spec_name=field.text("spec_name"),
        spec_digest=digest,
        seed=seed,
        objective=field.number("objective"),
        measures=field.numbers("measures"),
        theta=theta,
        theta_repaired=repaired,
        metrics=field.numbers("metrics", required=False, nullable=True),
        scenario_digest=scenario,
        failure_condition=str(data.get("failure_condition") or ""),
        format=version,
        outcome_digest=field.text("outcome_digest") if version >= 2 else "",
        outcome_parts=None if outcome_parts is None else {str(k): str(v) for k, v in outcome_parts.items()},
        why=tuple(why),
        seconds=field.number("seconds") if "seconds" in data else None,
        versions=field.mapping("versions"),
        origin=field.mapping("origin"),
    )


class _Fields:
    """Typed access to a corpus file's fields; every error names the file and the field."""

    def __init__(self, path: Path, data: dict[str, Any]) -> None:
        self.path, self.data = path, data

    def bad(self, name: str, message: str) -> CorpusError:
        value = self.data.get(name)
        shown = "" if name not in self.data else f" (got {value!r}, {type(value).__name__})"
        return CorpusError(f"{self.path}: field '{name}': {message}{shown}")

    def _get(self, name: str) -> Any:
        if name not in self.data:
            raise CorpusError(f"{self.path}: field '{name}' is missing")
        return self.data[name]

    def text(self, name: str) -> str:
        value = self._get(name)
        if not isinstance(value, str) or not value:
            raise self.bad(name, "must be a non-empty string")
        return value

    def integer(self, name: str) -> int:
        value = self._get(name)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.bad(name, "must be an integer")
        return value

    def number(self, name: str) -> float:
        value = self._get(name)
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise self.bad(name, "must be a finite number")
        return float(value)

    def numbers(self, name: str, *, required: bool = True, nullable: bool = False) -> dict[str, Any]:
        if not required and name not in self.data:
            return {}
        value = self._get(name)
        if not isinstance(value, dict) or (not value and required):
            raise self.bad(name, "must be a mapping of names to numbers")
        out: dict[str, Any] = {}
        for key, item in value.items():
            if item is None and nullable:
                out[str(key)] = None
            elif isinstance(item, bool) or not isinstance(item, int | float):
                raise CorpusError(f"{self.path}: field '{name}.{key}': must be a number (got {item!r})")
            else:
                out[str(key)] = float(item)
        return out

    def mapping(self, name: str) -> dict[str, Any] | None:
        value = self.data.get(name)
        if value is not None and not isinstance(value, dict):
            raise self.bad(name, "must be a mapping")
        return value


# --- writing -----------------------------------------------------------------------------------


def dump_entry(data: dict[str, Any]) -> str:
    """The text of a corpus file: the header comment, then the fields in a fixed order."""
    import yaml

    return HEADER + yaml.safe_dump(data, sort_keys=False, default_flow_style=False, width=100)


def set_status(path: Path, status: str) -> None:
    """Rewrites the ``status:`` line of a corpus file (atomically), leaving every other line alone."""
    from hritest.rundir import atomic_write

    if status not in STATUSES:
        raise CorpusError(f"status must be one of {', '.join(STATUSES)}, not {status!r}")
    text = Path(path).read_text()
    new, count = re.subn(r"^status:[^\n#]*", f"status: {status}", text, count=1, flags=re.MULTILINE)
    if count != 1:
        raise CorpusError(f"{path}: field 'status' is missing")
    atomic_write(Path(path), new)


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
    records = {r.index: r for r in run.evaluations()}
    ids = chosen([records[i] for i in replay.failure_ids(run, list(records.values()))], top)
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


def find_entries(corpus: Path, ids: list[str]) -> list[Path]:
    """The corpus files that ``ids`` name: an id, a file name, or a path (to the file or within the corpus).

    Raises:
        CorpusError: an id that names no entry, or more than one; nothing is returned then.
    """
    files = entry_files(corpus)
    found, unknown = [], []
    for ident in ids:
        name = ident.removesuffix(".yaml")
        matches = [f for f in files if name in (f.stem, str(f.relative_to(corpus).with_suffix("")))]
        if not matches and Path(ident).is_file():
            matches = [f for f in files if f.resolve() == Path(ident).resolve()]
        if len(matches) > 1:
            raise CorpusError(
                f"{ident!r} names {len(matches)} corpus entries "
                f"({', '.join(str(m.relative_to(corpus)) for m in matches)}); give spec/id"
            )
        (found.append(matches[0]) if matches else unknown.append(ident))
    if unknown:
        known = ", ".join(str(f.relative_to(corpus).with_suffix("")) for f in files[:30]) or "none"
        raise CorpusError(f"no corpus entry {', '.join(map(repr, unknown))} in {corpus}; its entries are: {known}")
    return found


def mark_fixed(corpus: Path, ids: list[str]) -> list[tuple[Path, str]]:
    """Sets ``status: fixed`` on the entries ``ids`` name; returns each path with its previous status.

    Every id is checked (and every file read) before any file is changed.
    """
    paths = find_entries(corpus, ids)
    before = [(path, load_entry(path).status) for path in paths]
    for path, status in before:
        if status != "fixed":
            set_status(path, "fixed")
    return before


def replay_entry(path: Path, *, tolerance: float = 1e-6) -> Replay:
    """Re-simulates a corpus entry (its raw theta and seed, with the spec it names, in this process)
    and compares with what it recorded.

    Raises:
        CorpusError: a malformed entry, a spec that is gone, or a theta of other labels.
        SpecError: its spec does not compile.
    """
    from hritest.domain import compile_spec
    from hritest.records import Status
    from hritest.replay import replay_outcome
    from hritest.spec import load_spec

    entry = load_entry(path)
    if not entry.spec_path.is_file():
        raise CorpusError(f"{path}: field 'spec' names {entry.spec_path}, which no longer exists")
    domain = compile_spec(load_spec(entry.spec_path))
    if list(entry.theta) != domain.space.labels:
        raise CorpusError(
            f"{path}: field 'theta' has components {', '.join(entry.theta)}, but {entry.spec_name}'s theta is "
            f"{', '.join(domain.space.labels)}"
        )
    stored = {
        "status": Status.OK,
        "failure": True,
        "objective": entry.objective,
        "measures": [entry.measures.get(m.name) for m in domain.measures],
    }
    replayed = replay_outcome(
        domain,
        theta=list(entry.theta.values()),
        seed=entry.seed,
        stored=stored,
        against=f"corpus entry {entry.spec_name}/{entry.id} as recorded",
        spec_digest=entry.spec_digest,
        tolerance=tolerance,
    )
    return replace(replayed, stored_why="; ".join(entry.why))
