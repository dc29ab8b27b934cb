"""The run directory: everything a search leaves behind, written so a kill loses nothing.

Layout of ``runs/<spec>-<timestamp>/``::

    spec.yaml          the spec as it was when the run started
    run.json           spec digest and origin, algorithm, seed, budget, versions, signature
    evaluations.jsonl  every finished evaluation, one JSON object a line, append-only
    occupancy.f32      its occupancy grids, fixed-size float32 records in the same order
                       (empty when the task declares no grids: records of size zero)
    checkpoint.pkl     the search's state at the last step (archives, scheduler, pending batch), signed
    .lock              held (flock) by the one search that writes the run
    progress.csv       evaluations, wall time, QD-score, coverage, best, failures
    archive.csv        the result archive's elites
    failures.yaml      the elites that meet the spec's failure condition

Whole files are replaced atomically (write a temporary file, then rename); the two append-only
files may end in a torn record after a kill, which :meth:`RunDirectory.evaluations` drops.

:meth:`RunDirectory.pack` and :func:`unpack` carry a run to another machine as one compressed
file, for a search that outlives the machine it started on (a long benchmark in a sandbox).

Loading a run executes nothing from it unless this user wrote it. The checkpoint is a pickle,
because the state it holds is pyribs schedulers, emitters and archives (numpy arrays, generators,
CMA-ES internals) and torch networks, which have no stable serialised form short of a converter
for each class and each version of them; so it is signed instead: an HMAC-SHA256 under a per-user
key (``$XDG_CONFIG_HOME/hritest/signing.key``, else ``~/.config/hritest/signing.key``, created
0600 on first use) precedes the pickle, and a checkpoint whose signature does not verify is never
unpickled unless the caller trusts the run. ``run.json`` is signed the same way, so that the
plugin files a run names (``file.py:Class`` relative to its ``spec_base``) run only when this user
started the run, when they lie in the user's project, or when the caller trusts the run
(:meth:`RunDirectory.plugin_base`).
"""

from __future__ import annotations

import csv
import fcntl
import hashlib
import hmac
import io
import json
import lzma
import math
import os
import pickle
import platform
import secrets
import shutil
import tarfile
import tempfile
from collections.abc import Collection, Iterator
from contextlib import contextmanager
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
LOCK_FILE = ".lock"  # hidden: pack() leaves it out
SIGNED = b"hritest signed checkpoint 1\n"  # then the HMAC-SHA256 of the pickle, then the pickle
MAC_SIZE = hashlib.sha256().digest_size
# Lock files held by this process, closed in children forked while they are held (pool workers),
# so that a worker outliving its search does not keep the run locked.
_HELD_LOCKS: set[int] = set()


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


def key_path() -> Path:
    """Where this user's signing key lives (XDG: a relative ``XDG_CONFIG_HOME`` is ignored)."""
    config = os.environ.get("XDG_CONFIG_HOME", "")
    root = Path(config) if os.path.isabs(config) else Path.home() / ".config"
    return root / "hritest" / "signing.key"


def signing_key() -> bytes:
    """This user's key for signing run directories, created (0600) on first use.

    Raises:
        RunDirectoryError: a key that others can read or write, or that is not this user's.
    """
    path = key_path()
    try:
        if not path.exists():
            _make_key(path)
        status = path.stat()
        key = path.read_bytes()
    except OSError as exc:
        raise RunDirectoryError(
            f"the signing key {path} cannot be made or read ({exc.strerror}); hritest signs run directories "
            "with it. Set XDG_CONFIG_HOME to a folder of yours that can be written"
        ) from None
    if status.st_uid != os.getuid() or status.st_mode & 0o077:
        raise RunDirectoryError(
            f"{path} is readable or writable by others (or not yours): anyone who can read it can make run "
            f"directories that hritest loads as yours. Run 'chmod 600 {path}' if it is yours, else delete it"
        )
    if len(key) < 32:
        raise RunDirectoryError(f"{path} is not a signing key (too short); delete it and a new one is made")
    return key


def _make_key(path: Path) -> None:
    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".signing.key.")  # 0600
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(secrets.token_bytes(32))
            handle.flush()
            os.fsync(handle.fileno())
        os.link(tmp, path)  # never over a key another process made meanwhile
    except FileExistsError:
        pass
    finally:
        Path(tmp).unlink(missing_ok=True)


def sign(data: bytes) -> bytes:
    """HMAC-SHA256 of ``data`` under this user's key."""
    return hmac.new(signing_key(), data, hashlib.sha256).digest()


def _meta_signature(meta: dict[str, Any]) -> str:
    fields = {k: v for k, v in meta.items() if k != "signature"}
    return sign(json.dumps(fields, sort_keys=True, separators=(",", ":")).encode()).hex()


def _close_held_locks_in_child() -> None:
    for fd in _HELD_LOCKS:
        os.close(fd)
    _HELD_LOCKS.clear()


os.register_at_fork(after_in_child=_close_held_locks_in_child)


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

    def __init__(self, path: Path, meta: dict[str, Any]) -> None:
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
        spec = Path(spec_file).read_bytes()  # read once: the copy is exactly what the digest covers
        meta = {
            "format": FORMAT,
            "spec_file": str(Path(spec_file).resolve()),
            "spec_digest": hashlib.sha256(spec).hexdigest(),
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
            "versions": versions(),
            **meta,
        }
        meta["signature"] = _meta_signature(meta)  # before the folder: a key that fails leaves nothing
        try:
            path.mkdir(parents=True, exist_ok=True)
            atomic_write(path / "spec.yaml", spec)
            atomic_write(path / RUN_FILE, json.dumps(meta, indent=2))
            (path / LOCK_FILE).touch()
        except OSError as exc:
            raise RunDirectoryError(
                f"cannot write the run directory {path} ({exc.strerror or exc}); choose a writable place with --out"
            ) from None
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
        for name, kind in (("spec_file", str), ("spec_digest", str), ("spec_base", str), ("seed", int)):
            if name in meta and not isinstance(meta[name], kind):
                raise RunDirectoryError(
                    f"{path / RUN_FILE}: {name} is {meta[name]!r}, not a {kind.__name__}; the file is corrupt"
                )
        limit = meta.get("time_limit")
        if limit is not None and not (isinstance(limit, int | float) and 0 < limit < math.inf):
            raise RunDirectoryError(
                f"{path / RUN_FILE}: time_limit is {limit!r}, not a number of seconds; the file is corrupt"
            )
        return cls(path, meta)

    # --- provenance and the one writer -------------------------------------------------------

    @property
    def written_by_me(self) -> bool:
        """Whether ``run.json`` carries this user's signature: this user started the run."""
        signature = self.meta.get("signature")
        return isinstance(signature, str) and hmac.compare_digest(signature, _meta_signature(self.meta))

    def update_meta(self, **changes: Any) -> None:
        """Sets fields of ``run.json`` and signs it again: for the run's one writer, under its lock."""
        meta = {**self.meta, **changes}
        self.meta = {**meta, "signature": _meta_signature(meta)}
        atomic_write(self.path / RUN_FILE, json.dumps(self.meta, indent=2))

    def adopt(self) -> None:
        """Signs ``run.json`` and the checkpoint with this user's key, unread: the user vouches for
        a run written by someone else, or by themselves on another machine (a packed run)."""
        self.update_meta()
        path = self.path / "checkpoint.pkl"
        if path.exists():
            raw = path.read_bytes()
            data = raw[len(SIGNED) + MAC_SIZE :] if raw.startswith(SIGNED) else raw
            atomic_write(path, SIGNED + sign(data) + data)

    def check_spec(self) -> None:
        """Checks that ``spec.yaml`` is the spec the run started with (the digest in ``run.json``).

        Raises:
            RunDirectoryError: it was edited; the message says how to get back.
        """
        if digest(self.path / "spec.yaml") != self.meta.get("spec_digest"):
            raise RunDirectoryError(
                f"{self.path / 'spec.yaml'} is not the spec this run was started with (its digest differs from "
                f"the one in {self.path / RUN_FILE}); the evaluations so far belong to the other one. Restore "
                "the file, or start a new search with the edited spec"
            )

    def plugin_base(self, *, trust: bool = False) -> Path | None:
        """The folder the run's ``file.py:Class`` plugin paths are relative to (its ``spec_base``),
        once it is safe to import them.

        Plugin files named by a run that this user did not start (``run.json`` not signed with
        this user's key: a run from someone else, or from before runs were signed) must lie in
        the user's project, which is the current working directory and below it, outside the run
        directory itself; ``trust`` lifts that.

        Raises:
            RunDirectoryError: a plugin file outside the project; the message says what to do.
        """
        from hritest.plugin_loader import registered
        from hritest.spec import load_spec

        base = self.meta.get("spec_base")
        folder = Path(base) if base else self.path
        if trust or self.written_by_me:
            return Path(base) if base else None
        spec = load_spec(self.path / "spec.yaml")
        project, here = Path.cwd().resolve(), self.path.resolve()
        for ref in (spec.task.name, spec.robot.policy, spec.human.policy):
            module = registered().get(ref, ref).rpartition(":")[0]
            path = (folder / module).resolve()
            if module.endswith(".py") and (not path.is_relative_to(project) or path.is_relative_to(here)):
                raise RunDirectoryError(
                    f"{self.path} was not started by you (its {RUN_FILE} is not signed with your key), and its "
                    f"spec names the plugin file {path}, which lies outside your project ({project}, the folder "
                    "you run hritest in, less the run directory): importing it would run code that came with "
                    "the run. Run hritest from the project that holds the file, or, if you trust whoever "
                    "wrote this run, give --trust (hritest search --resume, report and replay take it)"
                )
        return Path(base) if base else None

    @contextmanager
    def lock(self) -> Iterator[None]:
        """Holds the run's lock: one search writes a run directory at a time.

        Raises:
            RunDirectoryError: another process holds it (or the folder cannot be written).
        """
        path = self.path / LOCK_FILE
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        except OSError as exc:
            raise RunDirectoryError(f"{path} cannot be opened ({exc.strerror}); the run cannot be written") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 32).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise RunDirectoryError(
                f"{self.path} is being written by another search (process {holder}); two searches in one run "
                "would evaluate the same scenarios twice. Wait for it to finish, or stop it and resume then"
            ) from None
        _HELD_LOCKS.add(fd)
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            yield
        finally:
            _HELD_LOCKS.discard(fd)
            os.close(fd)  # releases the lock

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
        """Every committed evaluation, in order (a torn last line from a kill is dropped). A long
        run's records do not fit in memory: read those a command needs with
        :meth:`evaluations_of`, or go through them with :meth:`iter_evaluations`."""
        return list(self.iter_evaluations())

    def has_evaluations(self) -> bool:
        """Whether the run has a committed evaluation (reading its first line only)."""
        return next(self.iter_evaluations(), None) is not None

    def evaluations_of(self, indices: Collection[int]) -> dict[int, EvaluationRecord]:
        """The committed evaluations with these indices, by index, read one line at a time (a
        million teleoperation records take gigabytes; a report needs a few hundred of them)."""
        wanted = set(indices)
        return {r.index: r for r in self.iter_evaluations() if r.index in wanted}

    def iter_evaluations(self) -> Iterator[EvaluationRecord]:
        """:meth:`evaluations` one at a time, for a run too long to hold in memory."""
        path = self.path / "evaluations.jsonl"
        if not path.exists():
            return
        with open(path) as handle:
            previous = None
            for number, line in enumerate(handle, start=1):
                if previous is not None:
                    yield _record(path, number - 1, previous)
                previous = line
            if previous is not None and (last := _record(path, number, previous, last=True)) is not None:
                yield last

    def occupancy(self, shape: tuple[int, ...]) -> np.ndarray:
        """``(evaluations, *shape)`` occupancy grids of the evaluations whose records are written,
        memory-mapped (read from disk only when indexed).

        With grids that is every committed evaluation, and maybe one more whose line is not yet
        written; callers keep as many rows as they read lines. Zero-size records (a task without
        grids) leave no trace in the file, so their number is that of the committed evaluations.
        """
        size = int(np.prod(shape))
        if size == 0:
            return np.zeros((sum(1 for _ in self.iter_evaluations()), *shape), np.float32)
        path = self.path / "occupancy.f32"
        count = (path.stat().st_size if path.exists() else 0) // (4 * size)
        if count == 0:
            return np.zeros((0, *shape), np.float32)
        return np.memmap(path, dtype=np.float32, mode="r", shape=(count, *shape))

    def truncate(self, count: int, shape: tuple[int, ...]) -> None:
        """Cuts both append-only files back to ``count`` committed evaluations (used on resume),
        reading no more of them than it keeps."""
        path = self.path / "evaluations.jsonl"
        if path.exists():
            with open(path, "r+b") as handle:
                for _ in range(count):
                    handle.readline()
                handle.truncate(handle.tell())
        grids = self.path / "occupancy.f32"
        if grids.exists():
            with open(grids, "r+b") as handle:
                handle.truncate(count * int(np.prod(shape)) * 4)

    # --- state and summaries -----------------------------------------------------------------

    def save_checkpoint(self, state: object) -> None:
        """Writes ``state`` as the checkpoint, pickled and signed with this user's key."""
        data = pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL)
        atomic_write(self.path / "checkpoint.pkl", SIGNED + sign(data) + data)

    def load_checkpoint(self, *, trust: bool = False) -> object | None:
        """The checkpointed state (``None`` without a checkpoint), unpickled only once its signature
        shows this user wrote it, or if the caller trusts the run (``trust``).

        Raises:
            RunDirectoryError: unsigned, signed with another key, altered, or corrupt.
        """
        path = self.path / "checkpoint.pkl"
        if not path.exists():
            return None
        raw = path.read_bytes()
        signed = raw.startswith(SIGNED)
        data = raw[len(SIGNED) + MAC_SIZE :] if signed else raw
        if not trust and not (signed and hmac.compare_digest(raw[len(SIGNED) : len(SIGNED) + MAC_SIZE], sign(data))):
            why = (
                "its signature does not match your key: another user wrote it, or it was altered since"
                if signed
                else "it is not signed: another user wrote it, or a hritest from before checkpoints were signed"
            )
            raise RunDirectoryError(
                f"{path} was not loaded: {why}. Loading a checkpoint runs whatever code it holds, so hritest "
                f"loads only those signed with your key ({key_path()}). Start a new search; or, if you trust "
                "whoever wrote this run, give --trust (hritest search --resume and hritest report take it)"
            )
        try:
            return pickle.loads(data)
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


def _record(path: Path, number: int, line: str, *, last: bool = False) -> EvaluationRecord | None:
    """Line ``number`` of ``evaluations.jsonl``; a torn ``last`` line (a kill mid-write) is None."""
    try:
        return EvaluationRecord.from_json(json.loads(line))
    except json.JSONDecodeError:
        if last:
            return None
        raise RunDirectoryError(f"{path}:{number} is corrupt; the run cannot be read") from None
    except (KeyError, ValueError, TypeError) as exc:
        raise RunDirectoryError(
            f"{path}:{number} is not an evaluation record ({type(exc).__name__}: {exc}); the run cannot be read"
        ) from None


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
