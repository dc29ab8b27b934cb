"""Evaluating many scenarios in parallel without letting any one of them stop the search.

Jobs go to a ``concurrent.futures.Executor``: a local process pool by default, or a Dask
cluster's executor, so the search does not know which. Results stream back as they finish.
Faults are contained: an evaluation that raises or returns NaN is already an Evaluation with a
status (see :mod:`hritest.evaluate`); one that runs past the per-scenario timeout is stopped in
its worker (or, if it does not yield, its worker is killed); a worker that dies takes down only
the jobs it held. Every failed job is retried once, on its own when a crash is suspected, so a
scenario that kills its worker cannot take its neighbours' retries with it.
"""

from __future__ import annotations

import concurrent.futures as cf
import ctypes
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, replace
from functools import cache
from pathlib import Path

import numpy as np

from hritest import interrupt
from hritest.evaluate import evaluate
from hritest.records import Evaluation, Status

PR_SET_PDEATHSIG = 1  # from <sys/prctl.h>


@dataclass(frozen=True)
class DomainRef:
    """How a worker finds the domain: the spec file and the folder its plugin paths are relative to.

    Workers compile the spec once and keep it, so a job carries only theta and a seed.
    """

    spec: str
    base: str


@dataclass(frozen=True)
class Job:
    index: int
    theta: np.ndarray
    seed: int


class EvaluationTimeout(BaseException):
    """Raised inside a worker when an evaluation runs past its time limit.

    A BaseException, so that a plugin's ``except Exception`` (or evaluate's own) cannot swallow it.
    """


@cache
def _domain(ref: DomainRef):  # noqa: ANN202 - a Domain
    from hritest.domain import load_domain

    return load_domain(ref.spec, base=Path(ref.base))


def worker_init() -> None:
    """One thread per worker (the pool already uses every core); Ctrl-C is the parent's to handle,
    and a worker dies with its parent, however the parent ends (even by SIGKILL)."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    interrupt.ignore_in_worker()
    _die_with_parent()
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:  # torch is a dependency, but a worker needs none of it
        pass


def run_job(ref: DomainRef, job: Job, timeout: float) -> Evaluation:
    """Evaluates one job in a worker, stopping it after ``timeout`` seconds where signals allow."""
    domain = _domain(ref)
    on_main = threading.current_thread() is threading.main_thread()
    if on_main and timeout > 0:
        previous = signal.signal(signal.SIGALRM, _raise_timeout)
        signal.setitimer(signal.ITIMER_REAL, timeout)
    try:
        return evaluate(domain, job.theta, seed=job.seed)
    except EvaluationTimeout:
        return _failed(job, Status.TIMEOUT, f"the evaluation ran past its {timeout:g} s limit and was stopped")
    finally:
        if on_main and timeout > 0:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)


def _raise_timeout(signum, frame) -> None:  # noqa: ANN001 - a signal handler: (int, frame object)
    raise EvaluationTimeout


def _die_with_parent() -> None:
    """Asks Linux to SIGKILL this process when its parent dies (elsewhere, a no-op: there the
    parent's own shutdown is all that stops its workers)."""
    if not sys.platform.startswith("linux"):
        return
    parent = os.getppid()
    try:
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # the parent died before the request took effect
        os._exit(1)


def _failed(job: Job, status: Status, message: str) -> Evaluation:
    theta = np.asarray(job.theta, dtype=float)
    return Evaluation(
        theta=theta,
        theta_repaired=theta,
        repair_cost=float("nan"),
        regions={},
        seed=job.seed,
        status=status,
        message=message,
    )


def local_pool(workers: int) -> cf.ProcessPoolExecutor:
    return cf.ProcessPoolExecutor(max_workers=workers, initializer=worker_init)


class Evaluator:
    """Runs jobs on an executor with retries, timeouts and crash isolation.

    Args:
        ref: the domain the workers evaluate.
        make_executor: builds a fresh executor (called again after a worker dies).
        workers: how many jobs run at once; twice as many are kept submitted, so that no worker
            waits for the parent between two jobs.
        timeout: seconds one scenario may take; a worker stuck past twice that (counted from
            submission, so a job's time in the queue is covered by the slack) is killed.
    """

    def __init__(
        self,
        *,
        ref: DomainRef,
        make_executor: Callable[[], cf.Executor],
        workers: int,
        timeout: float,
        on_close: Callable[[], None] = lambda: None,
    ) -> None:
        self.ref, self.make_executor, self.workers, self.timeout = ref, make_executor, workers, timeout
        self.on_close = on_close
        self.executor = make_executor()

    def close(self) -> None:
        _shutdown(self.executor)
        self.on_close()

    def run(
        self, jobs: Iterable[Job], on_result: Callable[[Job, Evaluation], None], *, deadline: float | None = None
    ) -> None:
        """Evaluates every job, calling ``on_result`` for each as it finishes (in any order).

        After ``deadline`` (a ``time.monotonic()`` value) no job is started that was never
        started before; those started finish (retries included), so the jobs evaluated are a
        prefix of ``jobs``, in their order.

        If anything stops it (an interrupt, an error in ``on_result``), the jobs in flight are
        abandoned and the local pool's workers killed, so that none outlives the search.
        """
        try:
            self._run(jobs, on_result, deadline)
        except BaseException:
            self._kill_workers()
            raise

    def _run(self, jobs: Iterable[Job], on_result: Callable[[Job, Evaluation], None], deadline: float | None) -> None:
        queue = list(jobs)[::-1]  # pop() takes them in order; a job put back is appended, so popped next
        suspects: list[Job] = []  # jobs in flight when a worker died: rerun one at a time
        attempts: dict[int, int] = {}
        running: dict[cf.Future, tuple[Job, float]] = {}
        isolated: set[int] = set()  # suspects submitted: nothing may run beside them
        started: set[int] = set()

        def startable() -> bool:  # every job put back sits after the fresh ones: the last decides
            return bool(queue) and (deadline is None or queue[-1].index in started or time.monotonic() < deadline)

        while startable() or suspects or running:
            alone = suspects or any(job.index in isolated for job, _ in running.values())
            capacity = 1 if alone else 2 * self.workers  # one queued per worker: no idle gap
            broken = False
            while len(running) < capacity and (suspects or startable()):
                from_suspects = bool(suspects)
                job = suspects.pop() if from_suspects else queue.pop()
                started.add(job.index)  # before submitting: a job put back unsubmitted still runs
                try:
                    future = self.executor.submit(run_job, self.ref, job, self.timeout)
                except BrokenProcessPool:  # a worker died before we saw it: not this job's doing
                    (suspects if from_suspects else queue).append(job)
                    broken = True
                    break
                if from_suspects:
                    isolated.add(job.index)
                running[future] = (job, time.monotonic())
            if broken:
                self._crashed(running, attempts, suspects, on_result)
                continue
            done, _ = cf.wait(running, timeout=1.0, return_when=cf.FIRST_COMPLETED)
            if not done and self._kill_stuck(running):
                for job, started in running.values():
                    if time.monotonic() - started >= self._hard_limit:
                        self._retry_or_report(
                            job,
                            attempts,
                            queue,
                            on_result,
                            Status.TIMEOUT,
                            f"the evaluation ran past {self._hard_limit:g} s and its worker was killed",
                        )
                    else:
                        queue.append(job)  # an innocent bystander: no attempt counted
                self._restart(running)
                continue
            broken = False
            for future in done:
                job, _ = running.pop(future)
                try:
                    evaluation = future.result()
                except (BrokenProcessPool, cf.CancelledError):
                    broken = True
                    self._retry_or_report(
                        job,
                        attempts,
                        suspects,
                        on_result,
                        Status.CRASHED,
                        "the worker process died while evaluating this scenario",
                    )
                    continue
                except Exception as exc:
                    evaluation = _failed(job, Status.CRASHED, f"{type(exc).__name__}: {exc}")
                if evaluation.ok or attempts.get(job.index, 0) >= 1:
                    on_result(job, _note_retry(evaluation, attempts.get(job.index, 0)))
                else:
                    attempts[job.index] = 1
                    queue.append(job)
            if broken:
                self._crashed(running, attempts, suspects, on_result)

    def _crashed(
        self, running: dict, attempts: dict[int, int], suspects: list[Job], on_result: Callable[[Job, Evaluation], None]
    ) -> None:
        """A worker died: every job in flight becomes a suspect, rerun alone, then the pool restarts."""
        for job, _ in running.values():
            self._retry_or_report(
                job,
                attempts,
                suspects,
                on_result,
                Status.CRASHED,
                "the worker process died while evaluating this scenario",
            )
        self._restart(running)

    @property
    def _hard_limit(self) -> float:
        return 2 * self.timeout + 5

    def _restart(self, running: dict) -> None:
        running.clear()
        _shutdown(self.executor)
        self.executor = self.make_executor()

    def _retry_or_report(
        self,
        job: Job,
        attempts: dict[int, int],
        again: list[Job],
        on_result: Callable[[Job, Evaluation], None],
        status: Status,
        message: str,
    ) -> None:
        if attempts.get(job.index, 0) >= 1:
            on_result(job, _failed(job, status, message + " (also on its retry)"))
        else:
            attempts[job.index] = 1
            again.append(job)

    def _kill_stuck(self, running: dict[cf.Future, tuple[Job, float]]) -> bool:
        """Kills the local pool's workers when a job is far past its timeout; True if it did."""
        if self.timeout <= 0 or not running:
            return False
        if all(time.monotonic() - started < self._hard_limit for _, started in running.values()):
            return False
        self._kill_workers()
        return True

    def _kill_workers(self) -> None:
        """Kills the local pool's workers (a Dask executor's belong to the cluster: they stay)."""
        # ProcessPoolExecutor has no public way to stop a worker that ignores signals (C code stuck).
        processes = list((getattr(self.executor, "_processes", None) or {}).values())
        for process in processes:
            process.kill()
        for process in processes:
            process.join(timeout=5)


def _shutdown(executor: cf.Executor) -> None:
    """Stops ``executor``; a local pool (idle by now, or its workers killed) is waited for.

    Waiting matters there: a process pool left to shut down on its own races the interpreter's
    exit, whose hook writes to a pipe the pool's manager thread may be closing at that moment
    (CPython 3.11 prints "OSError: Bad file descriptor" on a search stopped by SIGTERM). A Dask
    executor is not: waiting would let the cluster finish the jobs in flight, where not waiting
    cancels them.
    """
    try:
        executor.shutdown(wait=isinstance(executor, cf.ProcessPoolExecutor), cancel_futures=True)
    except TypeError:  # Dask's ClientExecutor predates cancel_futures
        executor.shutdown(wait=False)


def _note_retry(evaluation: Evaluation, attempts: int) -> Evaluation:
    if attempts and not evaluation.ok:
        return replace(evaluation, message=f"{evaluation.message} (also on its retry)")
    return evaluation
