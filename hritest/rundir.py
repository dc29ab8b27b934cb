"""The run directory: everything a search leaves behind, written so a kill loses nothing.

Layout of ``runs/<spec>-<timestamp>/``::

    spec.yaml          the spec as it was when the run started
    run.json           spec digest and origin, algorithm, seed, budget, versions
    evaluations.jsonl  every finished evaluation, one JSON object a line, append-only
    occupancy.f32      its occupancy grids, fixed-size float32 records in the same order
                       (empty when the task declares no grids: records of size zero)
    checkpoint.pkl     the search's state at the last step (archives, scheduler, pending batch)
    progress.csv       evaluations, wall time, QD-score, coverage, best, failures
    archive.csv        the result archive's elites
    failures.yaml      the elites that meet the spec's failure condition

Whole files are replaced atomically (write a temporary file, then rename); the two append-only
files may end in a torn record after a kill, which :meth:`RunDirectory.evaluations` drops.

:meth:`RunDirectory.pack` and :func:`unpack` carry a run to another machine as one compressed
file, for a search that outlives the machine it started on (a long benchmark in a sandbox).
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import lzma
import os
import pickle
import platform
import shutil
import tarfile
import tempfile
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from hritest.errors import HritestError
from hritest.records import EvaluationRecord

RUN_FILE = "run.json"
FORMAT = 1
# The order pack() reads a live run in: the checkpoint before the evaluations it counts, each
# evaluation's line before its occupancy record (the reverse of the order they are written in).
PACK_FIRST = ("checkpoint.pkl", "evaluations.jsonl", "occupancy.f32")


class RunDirectoryError(HritestError):
    """A folder that is not a usable hritest run directory."""


def atomic_write(path: Path, data: bytes | str) -> None:
    """Writes ``path`` so that readers see the old file or the new one, never a part."""
    raw = data.encode() if isinstance(data, str) else data
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        os.fchmod(fd, 0o644)  # mkstemp's 0600 would hide a run from the rest of a team
        with os.fdopen(fd, "wb") as handle:
            handle.write(raw)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def digest(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def versions() -> dict[str, str]:
    from importlib.metadata import PackageNotFoundError, version

    found = {"python": platform.python_version(), "machine": platform.machine()}
    for package in ("hritest", "numpy", "ribs", "mujoco", "ortools", "torch"):
        try:
            found[package] = version(package)
        except PackageNotFoundError:
            found[package] = "missing"
    return found


class RunDirectory:
    """One search's folder. Create with :meth:`create`, reopen with :meth:`open`."""

    def __init__(self, path: Path, meta: dict[str, Any]):
        self.path = Path(path)
        self.meta = meta

    @classmethod
    def create(
        cls, *, root: Path, spec_file: Path, name: str, meta: dict[str, Any], folder: Path | None = None
    ) -> RunDirectory:
        """A new run folder under ``root`` (or exactly ``folder``), with the spec and ``run.json``."""
        stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
        path = Path(folder) if folder else Path(root) / f"{name}-{stamp}"
        if path.exists() and any(path.iterdir()):
            raise RunDirectoryError(f"{path} already exists and is not empty; choose another --out or remove it")
        path.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(spec_file, path / "spec.yaml")
        meta = {
            "format": FORMAT,
            "spec_file": str(Path(spec_file).resolve()),
            "spec_digest": digest(spec_file),
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
            "versions": versions(),
            **meta,
        }
        atomic_write(path / RUN_FILE, json.dumps(meta, indent=2))
        return cls(path, meta)

    @classmethod
    def open(cls, path: Path) -> RunDirectory:
        """Reopens a run folder, checking that it is one.

        Raises:
            RunDirectoryError: missing folder, missing or unreadable ``run.json``, foreign format.
        """
        path = Path(path)
        if not path.is_dir():
            raise RunDirectoryError(f"{path} is not a folder; give the run directory that 'hritest search' wrote")
        try:
            meta = json.loads((path / RUN_FILE).read_text())
        except FileNotFoundError:
            raise RunDirectoryError(f"{path} has no {RUN_FILE}: it is not a hritest run directory") from None
        except (OSError, json.JSONDecodeError) as exc:
            raise RunDirectoryError(f"{path / RUN_FILE} is corrupt ({exc}); the run cannot be read") from None
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise RunDirectoryError(f"{path / RUN_FILE} is not a hritest run (format {FORMAT}) file")
        if not (path / "spec.yaml").is_file():
            raise RunDirectoryError(f"{path} has no spec.yaml; the run cannot be resumed or reported")
        return cls(path, meta)

    def pack(self) -> bytes:
        """The whole folder as an xz-compressed tar, safe to take while the search runs.

        Whatever the search writes meanwhile, the result is a state a kill could have left, which
        resuming handles: the checkpoint is read first, and every evaluation it counts was
        appended before it was written; an evaluation's line is read before the occupancy file,
        which gets each record before its line. Atomic replacements are read whole, old or new.
        """
        names = [*PACK_FIRST, *sorted(p.name for p in self.path.iterdir() if p.name not in PACK_FIRST)]
        buffer = io.BytesIO()
        with tarfile.open(fileobj=buffer, mode="w:xz", preset=9) as tar:
            for name in names:
                path = self.path / name
                if path.is_file() and not name.startswith("."):  # not atomic_write's temporary files
                    tar.add(path, arcname=f"{self.path.name}/{name}")
        return buffer.getvalue()

    # --- evaluations -------------------------------------------------------------------------

    def append(self, record: EvaluationRecord, occupancy: np.ndarray | None, shape: tuple[int, ...]) -> None:
        """Appends one evaluation: its occupancy record first, then its line (which commits it)."""
        grid = np.zeros(shape, np.float32) if occupancy is None else np.asarray(occupancy, np.float32)
        with open(self.path / "occupancy.f32", "ab") as handle:
            handle.write(grid.tobytes())
        with open(self.path / "evaluations.jsonl", "a") as handle:
            handle.write(json.dumps(record.to_json(), separators=(",", ":")) + "\n")

    def evaluations(self) -> list[EvaluationRecord]:
        """Every committed evaluation, in order (a torn last line from a kill is dropped)."""
        path = self.path / "evaluations.jsonl"
        if not path.exists():
            return []
        lines = path.read_text().splitlines()
        records = []
        for number, line in enumerate(lines, start=1):
            try:
                records.append(EvaluationRecord.from_json(json.loads(line)))
            except json.JSONDecodeError:
                if number != len(lines):
                    raise RunDirectoryError(f"{path}:{number} is corrupt; the run cannot be read") from None
            except (KeyError, ValueError, TypeError) as exc:
                raise RunDirectoryError(
                    f"{path}:{number} is not an evaluation record ({type(exc).__name__}: {exc}); the run cannot be read"
                ) from None
        return records

    def occupancy(self, shape: tuple[int, ...]) -> np.ndarray:
        """``(evaluations, *shape)`` occupancy grids of the evaluations whose records are written.

        With grids that is every committed evaluation, and maybe one more whose line is not yet
        written; callers keep as many rows as they read lines. Zero-size records (a task without
        grids) leave no trace in the file, so their number is that of the committed evaluations.
        """
        size = int(np.prod(shape))
        if size == 0:
            return np.zeros((len(self.evaluations()), *shape), np.float32)
        path = self.path / "occupancy.f32"
        data = np.fromfile(path, dtype=np.float32) if path.exists() else np.zeros(0, np.float32)
        count = len(data) // size
        return data[: count * size].reshape(count, *shape)

    def truncate(self, count: int, shape: tuple[int, ...]) -> None:
        """Cuts both append-only files back to ``count`` committed evaluations (used on resume)."""
        lines = (self.path / "evaluations.jsonl").read_text().splitlines(keepends=True) if count else []
        atomic_write(self.path / "evaluations.jsonl", "".join(lines[:count]))
        path = self.path / "occupancy.f32"
        if path.exists():
            with open(path, "r+b") as handle:
                handle.truncate(count * int(np.prod(shape)) * 4)

    # --- state and summaries -----------------------------------------------------------------

    def save_checkpoint(self, state: dict[str, Any]) -> None:
        atomic_write(self.path / "checkpoint.pkl", pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL))

    def load_checkpoint(self) -> dict[str, Any] | None:
        path = self.path / "checkpoint.pkl"
        if not path.exists():
            return None
        try:
            return pickle.loads(path.read_bytes())
        except Exception as exc:
            raise RunDirectoryError(f"{path} is corrupt ({type(exc).__name__}); the run cannot be resumed") from None

    def write_csv(self, name: str, rows: list[dict[str, Any]]) -> None:
        buffer = io.StringIO()
        if rows:
            writer = csv.DictWriter(buffer, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        atomic_write(self.path / name, buffer.getvalue())

    def write_text(self, name: str, text: str) -> None:
        atomic_write(self.path / name, text)


def unpack(archive: Path, into: Path) -> RunDirectory:
    """Unpacks a :meth:`RunDirectory.pack` file as a new folder under ``into``; resume it from there.

    Raises:
        RunDirectoryError: not such a file, or its run folder exists already under ``into``.
    """
    archive, into = Path(archive), Path(into)
    try:
        with tarfile.open(archive, mode="r:*") as tar:
            members = tar.getmembers()
            tops = {Path(m.name).parts[0] for m in members}
            if len(tops) != 1 or f"{next(iter(tops))}/{RUN_FILE}" not in {m.name for m in members}:
                raise RunDirectoryError(
                    f"{archive} holds no single run folder; give a file that "
                    "RunDirectory.pack (benchmarks/stash.py save) wrote"
                )
            target = into / tops.pop()
            if target.exists():
                raise RunDirectoryError(
                    f"{target} exists already; resume it there, or move it away to unpack {archive} in its place"
                )
            into.mkdir(parents=True, exist_ok=True)
            staging = Path(tempfile.mkdtemp(dir=into, prefix=".unpack-"))
            try:  # into a hidden folder first, so a failure leaves no half-unpacked run behind
                tar.extractall(staging, filter="data")
                os.replace(staging / target.name, target)
            finally:
                shutil.rmtree(staging, ignore_errors=True)
    except (OSError, tarfile.TarError, lzma.LZMAError, EOFError) as exc:
        raise RunDirectoryError(
            f"{archive} cannot be unpacked ({exc}); give a file that RunDirectory.pack (benchmarks/stash.py save) wrote"
        ) from None
    return RunDirectory.open(target)
