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

import math
import re
from dataclasses import dataclass, replace
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
    from hritest.errors import SpecError
    from hritest.spec.source import parse_yaml

    path = Path(path)
    try:
        data, _, duplicates = parse_yaml(path.read_text(), file=str(path))  # bounded: no alias bomb, no deep nest
    except OSError as exc:
        raise CorpusError(f"{path}: cannot be read ({exc.strerror})") from None
    except SpecError as exc:
        raise CorpusError(str(exc).replace("\n", "; ")) from None
    if duplicates:
        raise CorpusError(f"{duplicates[0]}")
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
    from hritest.domain import load_domain
    from hritest.records import Status
    from hritest.replay import replay_outcome

    entry = load_entry(path)
    if not entry.spec_path.is_file():
        raise CorpusError(f"{path}: field 'spec' names {entry.spec_path}, which no longer exists")
    domain = load_domain(entry.spec_path)
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
