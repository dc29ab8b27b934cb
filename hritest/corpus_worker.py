"""Replays corpus entries in a worker process of their own, with a time limit.

A corpus entry runs the user's plugin code. In the test process, a plugin that sleeps would hang
CI, and one that calls ``os._exit`` would end pytest with exit status 0; in a worker process each is
a verdict naming the entry. One worker serves a whole session (imports and compiled specs are paid
once) and is replaced after a timeout or a death.

The worker (``python -m hritest.corpus_worker``) reads one JSON request per line on stdin and
answers one JSON line on the original stdout; whatever plugins print goes to its stderr, a file
whose end is shown when the worker dies. Only the parent's side (:class:`ReplayWorker`,
:func:`replay_entry`) is imported by the pytest plugin, and it needs only the standard library
until an entry is judged.
"""

from __future__ import annotations

import json
import os
import select
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from hritest.corpus import Entry

COMPILE_SECONDS = 300.0  # default: worker start-up and compiling a spec (plugin imports, first numba compile)
SEED_SECONDS = 30.0  # added to five times an entry's recorded seconds, per replayed seed
UNKNOWN_SECONDS = 60.0  # per seed, for an entry that did not record how long it took (format 1)


class WorkerError(Exception):
    """The worker hung past its time limit or died; the message says which and how."""


def replay_seeds(entry: Entry, replays: int) -> list[int]:
    """The recorded seed first, then the ones after it: each can be replayed by hand with ``--seed``."""
    from hritest.records import MAX_SEED

    return [(entry.seed + k) % (MAX_SEED + 1) for k in range(replays)]


def seed_timeout(entry: Entry) -> float:
    """The default time limit of one replay: five times what the evaluation took when recorded, plus 30 s."""
    return UNKNOWN_SECONDS if entry.seconds is None else 5 * entry.seconds + SEED_SECONDS


class ReplayWorker:
    """One worker process, started on first use and restarted after a timeout or a death.

    ``compiled`` holds each spec's compile answer (its labels and outcome digest, or its error) for
    the whole session; a restarted worker compiles a spec again before replaying one of its entries.

    ``pythonpath`` is prepended to the worker's ``PYTHONPATH`` (the test process's ``sys.path``, so
    that ``module:Class`` plugins import there as they do here); ``cwd`` is where it runs.
    """

    def __init__(self, *, cwd: Path, pythonpath: list[str]) -> None:
        self.cwd, self.pythonpath = cwd, pythonpath
        self.process: subprocess.Popen | None = None
        self.log: Any = None
        self.compiled: dict[str, dict[str, Any]] = {}
        self.loaded: set[str] = set()  # the specs the current worker process has compiled

    def request(self, message: dict[str, Any], *, timeout: float, option: str) -> dict[str, Any]:
        """Sends ``message`` and returns the answer; ``option`` is the pytest option that sets ``timeout``.

        Raises:
            WorkerError: no answer within ``timeout`` seconds (the worker is killed; the message names
                ``option``), or the worker died.
        """
        if self.process is None:
            self._start()
        assert self.process is not None and self.process.stdin is not None and self.process.stdout is not None
        start = len(self._log_text())
        try:
            self.process.stdin.write((json.dumps(message) + "\n").encode())
            self.process.stdin.flush()
        except BrokenPipeError:
            pass  # it died: reading says how
        line = self._read_line(timeout)
        if line is None:
            self.close()
            raise WorkerError(
                f"did not finish within {timeout:g} s: a plugin that hangs? (raise the limit with {option})"
            )
        if not line:
            code = self.process.wait()
            tail = self._log_text()[start:][-2000:].strip()
            self.close()
            raise WorkerError(
                f"the replay process died (exit status {code}): a plugin that exits the process or crashes it"
                + (f"; its last output:\n{tail}" if tail else "")
            )
        return json.loads(line)

    def _start(self) -> None:
        self.log = tempfile.TemporaryFile()  # noqa: SIM115 - open as long as the worker runs
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([*self.pythonpath, *filter(None, [env.get("PYTHONPATH")])])
        self.process = subprocess.Popen(
            [sys.executable, "-m", "hritest.corpus_worker"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self.log,
            cwd=self.cwd,
            env=env,
        )
        self.loaded = set()

    def _read_line(self, timeout: float) -> bytes | None:
        """A line from the worker, ``b""`` at end of file, None after ``timeout`` seconds."""
        stdout = self.process.stdout
        deadline = time.monotonic() + timeout
        chunks = []
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([stdout], [], [], left)[0]:
                return None
            chunk = os.read(stdout.fileno(), 1 << 16)
            if not chunk:
                return b""
            chunks.append(chunk)
            if chunk.endswith(b"\n"):
                return b"".join(chunks)

    def _log_text(self) -> str:
        if self.log is None:
            return ""
        self.log.seek(0)
        return self.log.read().decode(errors="replace")

    def close(self) -> None:
        if self.process is not None:
            self.process.kill()
            self.process.wait()
            for pipe in (self.process.stdin, self.process.stdout):
                pipe.close()
            self.process = None
        if self.log is not None:
            self.log.close()
            self.log = None


def replay_entry(
    entry: Entry,
    *,
    worker: ReplayWorker,
    replays: int = 1,
    timeout: float | None = None,
    compile_timeout: float = COMPILE_SECONDS,
    project: Path | None,
) -> Any:
    """Replays ``entry`` with ``replays`` seeds (:func:`replay_seeds`) in ``worker`` and judges it.

    ``timeout`` limits each seed's replay (default :func:`seed_timeout`); ``compile_timeout`` the
    worker's start and the compiling of the entry's spec, once per spec (a project whose plugins
    import slowly, or a cold numba cache on a slow CI machine, may need more than the default).
    ``project`` is the folder the entry's spec must lie in, since compiling it runs the plugins it
    names (None: anywhere).
    Returns a :class:`hritest.verdict.Judgement`; nothing about the entry raises.
    """
    from hritest import verdict

    spec = entry.spec_path
    if not spec.is_file():
        return verdict.error(f"its spec {spec} no longer exists; restore it, or delete {entry.path}")
    if project is not None and not spec.is_relative_to(project.resolve()):
        return verdict.error(
            f"{entry.path}: field 'spec' names {spec}, outside the project {project}; replaying it would run "
            "the plugins it names. Move the spec into the project, or pass --hri-allow-outside to trust it"
        )
    key = str(spec)
    if key not in worker.compiled or ("error" not in worker.compiled[key] and key not in worker.loaded):
        try:
            worker.compiled[key] = worker.request(
                {"compile": key}, timeout=compile_timeout, option="--hri-compile-timeout"
            )
            worker.loaded.add(key)
        except WorkerError as exc:  # kept, so that the spec's other entries do not wait as long again
            worker.compiled[key] = {"error": f"compiling its spec: {exc}"}
    compiled = worker.compiled[key]
    if "error" in compiled:
        return verdict.error(compiled["error"])
    try:
        if list(entry.theta) != compiled["labels"]:
            return verdict.error(
                f"{entry.path}: field 'theta' has components {', '.join(entry.theta)}, but {entry.spec_name}'s "
                f"theta is {', '.join(compiled['labels'])}"
            )
        changes = verdict.changes_since(entry, parts_now=compiled["parts"], spec_digest_now=compiled["spec_digest"])
        seeds = replay_seeds(entry, replays)
        limit = (timeout if timeout is not None else seed_timeout(entry)) * len(seeds)
        answer = worker.request(
            {"replay": key, "theta": list(entry.theta.values()), "seeds": seeds}, timeout=limit, option="--hri-timeout"
        )
    except WorkerError as exc:
        return verdict.error(str(exc))
    if "error" in answer:
        return verdict.error(answer["error"], changes=changes)
    return verdict.judge(entry, [verdict.SeedReplay.from_json(r) for r in answer["replays"]], changes=changes)


# --- the worker's side -----------------------------------------------------------------------------


def _compile(spec: str, domains: dict[str, Any]) -> dict[str, Any]:
    from hritest.domain import load_domain
    from hritest.outcome_digest import outcome_digest
    from hritest.rundir import digest

    domains[spec] = domain = load_domain(spec)
    outcome = outcome_digest(domain)
    return {"labels": list(domain.space.labels), "parts": dict(outcome.parts), "spec_digest": digest(Path(spec))}


def _replay(request: dict[str, Any], domains: dict[str, Any]) -> dict[str, Any]:
    import numpy as np

    from hritest.evaluate import evaluate
    from hritest.verdict import SeedReplay

    domain = domains[request["replay"]]
    names = [m.name for m in domain.measures]
    theta = np.asarray(request["theta"], dtype=float)
    return {
        "replays": [
            SeedReplay.of(evaluate(domain, theta, seed=int(seed)), names).to_json() for seed in request["seeds"]
        ]
    }


def main() -> None:
    """The worker's loop: one request per stdin line, one answer per line on the original stdout."""
    import traceback

    from hritest.errors import HritestError
    from hritest.search.executor import _die_with_parent  # the pool workers' own: one way to do it

    _die_with_parent()  # a worker hanging in a plugin must not outlive pytest
    answers = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)  # what plugins print goes to stderr, never into the answers
    domains: dict[str, Any] = {}
    for line in sys.stdin:
        request = json.loads(line)
        try:
            answer = _compile(request["compile"], domains) if "compile" in request else _replay(request, domains)
        except HritestError as exc:
            answer = {"error": str(exc)}
        except BaseException as exc:  # a plugin's SystemExit or KeyboardInterrupt included: still an answer
            last = traceback.format_exception_only(exc)[-1].strip()
            answer = {"error": f"replaying it raised {last}\n{''.join(traceback.format_exception(exc))}"}
        answers.write(json.dumps(answer) + "\n")
        answers.flush()


if __name__ == "__main__":
    main()
