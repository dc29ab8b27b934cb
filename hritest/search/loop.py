"""The search loop: ask a batch, evaluate it in parallel, tell the results, checkpoint.

One batch at a time, so a run is reproducible: evaluations stream back in any order, but are
told to the scheduler in the order they were asked. The state (a
:class:`~hritest.search.state.SearchState`) is checkpointed after every ask and every tell, and each
finished evaluation is appended to the run directory the moment it arrives, so a killed run resumes
from its last checkpoint and re-evaluates nothing it finished.
"""

from __future__ import annotations

import math
import signal
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import yaml

from hritest import interrupt
from hritest.domain import Domain
from hritest.errors import HritestError
from hritest.interrupt import Interrupted
from hritest.records import Evaluation, EvaluationRecord, rank_failures
from hritest.rundir import RunDirectory, RunDirectoryError
from hritest.search import algorithms, archives
from hritest.search.executor import Evaluator, Job
from hritest.search.proposers import ModelFree, SurrogateAssisted, SurrogateOptions
from hritest.search.state import PendingBatch, ProgressRow, SearchState, check_resumable, evaluation_seed, load_state

SURROGATE = ("sas", "dsas")
# progress.csv, archive.csv and failures.yaml are rewritten at most this often (and at the end):
# between batches the workers wait, so the loop does only what resuming needs (the checkpoint).
SUMMARY_SECONDS = 5.0
ALGORITHMS = (*algorithms.MODEL_FREE, *SURROGATE)
ERROR_LOG = "error.log"  # the traceback of a bug in hritest that stopped the search


@dataclass(frozen=True)
class Snapshot:
    """Where a search stands, for progress displays.

    ``summary`` and ``failures`` (elites that meet the failure condition) are as of the last
    batch; ``failed`` counts the evaluations that did not complete; ``phase`` says what the
    search is doing (proposing a batch, which for SAS/DSAS is training the surrogate and searching
    it, or evaluating one).
    """

    evaluations: int
    budget: int
    summary: archives.Summary | None
    failures: int
    failed: int = 0
    phase: str = "evaluating"


class Search:
    """A model-free QD search over a domain, writing into a run directory.

    Build with :meth:`new` or :meth:`resume`; then :meth:`run`.
    """

    def __init__(
        self, *, domain: Domain, run: RunDirectory, state: SearchState, records: list[EvaluationRecord]
    ) -> None:
        self.domain, self.run_dir, self.state = domain, run, state
        self.records: dict[int, EvaluationRecord] = {r.index: r for r in records}
        self.occupancy_shape = occupancy_shape(domain)
        self.summarised = -math.inf
        self.failed = sum(not r.ok for r in records)  # evaluations that did not complete
        self.last = Snapshot(state.evaluations, state.budget, None, 0, self.failed)

    @classmethod
    def new(
        cls,
        *,
        domain: Domain,
        run: RunDirectory,
        algorithm: str,
        budget: int,
        seed: int,
        options: SurrogateOptions | None = None,
    ) -> Search:
        if algorithm in SURROGATE:
            proposer = SurrogateAssisted(
                domain, gradients=algorithm == "dsas", seed=seed, options=options or SurrogateOptions()
            )
        else:
            proposer = ModelFree(
                algorithms.scheduler(domain, algorithm, archives.search_archive(domain, seed=seed), seed=seed)
            )
        state = SearchState(
            algorithm=algorithm,
            budget=budget,
            seed=seed,
            proposer=proposer,
            result=archives.result_archive(domain, seed=seed),
        )
        run.save_checkpoint(state)
        return cls(domain=domain, run=run, state=state, records=[])

    @classmethod
    def resume(cls, *, domain: Domain, run: RunDirectory, trust: bool = False) -> Search:
        """The search of ``run`` as its checkpoint left it, after checking every file it reads.

        Only when every check passes are the evaluations the checkpoint never saw cut off (a
        torn last line, a batch asked after it); on any error nothing in the run has changed.

        Raises:
            RunDirectoryError: no checkpoint, one not written by this user (unless ``trust``), or
                files that disagree (see :func:`~hritest.search.state.check_resumable`).
        """
        state = load_state(run, trust=trust)
        if state is None:
            raise RunDirectoryError(f"{run.path} has no checkpoint.pkl; the run cannot be resumed")
        records = run.evaluations()
        shape = occupancy_shape(domain)
        keep = check_resumable(state, run=run, records=records, dim=domain.space.dim, grid_shape=shape)
        run.truncate(keep, shape)
        return cls(domain=domain, run=run, state=state, records=records[:keep])

    @property
    def evaluated(self) -> int:
        """Evaluations told so far."""
        return self.state.evaluations

    @property
    def done(self) -> bool:
        return self.state.evaluations >= self.state.budget

    def run(self, evaluator: Evaluator, progress: Callable[[Snapshot], None] = lambda s: None) -> None:
        """Runs batches until the budget is spent.

        Raises:
            Interrupted: on SIGINT or SIGTERM (see :mod:`hritest.interrupt`), naming the run
                directory, whose files are whole: ``--resume`` continues the run.
            Exception: a bug in hritest, its traceback written to ``error.log`` in the run
                directory, whose path the exception holds as ``traceback_file``.
        """
        try:
            while not self.done:
                self.step(evaluator, progress)
        except (Interrupted, KeyboardInterrupt) as exc:
            signum = exc.signum if isinstance(exc, Interrupted) else signal.SIGINT
            raise Interrupted(signum, run=self.run_dir.path) from None
        except HritestError:
            raise
        except Exception as exc:
            log = self.run_dir.path / ERROR_LOG
            self.run_dir.write_text(ERROR_LOG, "".join(traceback.format_exception(exc)))
            exc.traceback_file = log  # for the command line's one-line message
            raise

    def step(self, evaluator: Evaluator, progress: Callable[[Snapshot], None]) -> None:
        """One batch: ask (unless a resumed batch is pending), evaluate what is missing, tell."""
        started = time.monotonic()
        state = self.state
        if state.pending is None:
            progress(replace(self.snapshot(), phase="proposing"))
            solutions = state.proposer.ask(self)
            count = min(len(solutions), state.budget - state.evaluations)
            pending = PendingBatch(batch=state.batch + 1, solutions=solutions, first=state.evaluations, count=count)
            self.state = state = replace(state, batch=pending.batch, pending=pending)
            with interrupt.deferred():
                self.run_dir.save_checkpoint(state)
        pending = state.pending
        first, count, batch = pending.first, pending.count, pending.batch
        jobs = [
            Job(first + i, pending.solutions[i], evaluation_seed(state.seed, first + i))
            for i in range(count)
            if first + i not in self.records
        ]

        done = [count - len(jobs)]  # of this batch, finished before (a resumed batch) or now

        def finished(job: Job, evaluation: Evaluation) -> None:
            record = EvaluationRecord.of(evaluation, index=job.index, batch=batch)
            with interrupt.deferred():
                self.run_dir.append(record, evaluation.occupancy, self.occupancy_shape)
                self.records[job.index] = record
            self.failed += not record.ok
            done[0] += 1
            progress(self.snapshot(extra=done[0]))

        evaluator.run(jobs, finished)
        records = [self.records[first + i] for i in range(count)]
        state.proposer.tell(self, records, pending.solutions)
        self._add_to_result(records)
        summary = archives.Summary.of(state.result, self.domain.spec.objective.range)
        failures = self.failures()
        elapsed = state.elapsed + time.monotonic() - started
        row = ProgressRow(
            evaluations=state.evaluations + count,
            batch=batch,
            wall_time=round(elapsed, 3),
            qd_score=summary.qd_score,
            normalized_qd_score=summary.normalized_qd_score,
            coverage=summary.coverage,
            best=summary.best,
            failures=len(failures),
        )
        with interrupt.deferred():
            self.state = state = replace(
                state, evaluations=row.evaluations, pending=None, elapsed=elapsed, progress=(*state.progress, row)
            )
            self.run_dir.save_checkpoint(state)
        if self.done or time.monotonic() - self.summarised >= SUMMARY_SECONDS:
            self.write_summaries(failures)
            self.summarised = time.monotonic()
        self.last = Snapshot(state.evaluations, state.budget, summary, len(failures), self.failed)
        progress(self.last)

    def _add_to_result(self, records: list[EvaluationRecord]) -> None:
        """Adds the successful evaluations to the result archive with their raw objective."""
        good = [r for r in records if r.ok]
        if good:
            self.state.result.add(
                np.array([r.theta_repaired for r in good]),
                np.array([r.objective for r in good]),
                np.array([r.measures for r in good]),
                evaluation=np.array([r.index for r in good]),
            )

    def dataset(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Training data from every successful evaluation: raw theta, occupancy grids, targets.

        Targets are the regularised objective over the objective's range, then the measures. Rows
        are in evaluation order, not in the order the workers finished them (the files' order),
        so that training, and so the run, is the same whatever the number of workers.
        """
        lo, hi = self.domain.spec.objective.range
        order = [r.index for r in self.run_dir.evaluations()]
        grids = self.run_dir.occupancy(self.occupancy_shape)[: len(order)]
        rows = sorted(
            ((i, self.records[index]) for i, index in enumerate(order) if self.records[index].ok),
            key=lambda row: row[1].index,
        )
        theta = np.array([r.theta for _, r in rows], dtype=np.float32).reshape(len(rows), -1)
        targets = np.array([[r.search_objective / (hi - lo), *r.measures] for _, r in rows], dtype=np.float32).reshape(
            len(rows), -1
        )
        return theta, grids[[i for i, _ in rows]], targets

    def snapshot(self, extra: int = 0) -> Snapshot:
        """The last batch's snapshot, with ``extra`` evaluations of the current one finished."""
        return replace(self.last, evaluations=self.state.evaluations + extra, failed=self.failed, phase="evaluating")

    def failures(self) -> list[EvaluationRecord]:
        """The result archive's elites that meet the failure condition, worst first."""
        return rank_failures(self.records[int(i)] for i in self.state.result.data("evaluation"))

    def write_summaries(self, failures: list[EvaluationRecord]) -> None:
        names = [m.name for m in self.domain.measures]
        labels = self.domain.space.labels
        self.run_dir.write_csv("progress.csv", self.state.progress_rows())
        elites = sorted(
            (self.records[int(i)] for i in self.state.result.data("evaluation")),
            key=lambda r: (-r.objective, r.index),
        )
        self.run_dir.write_csv(
            "archive.csv",
            [
                {
                    "evaluation": r.index,
                    "objective": r.objective,
                    **dict(zip(names, r.measures)),
                    **dict(zip(labels, r.theta_repaired)),
                    "failure": r.failure,
                }
                for r in elites
            ],
        )
        self.run_dir.write_text(
            "failures.yaml",
            yaml.safe_dump(
                {
                    "spec": self.run_dir.meta.get("spec_file"),
                    "failure": self.domain.spec.failure,
                    "failures": [
                        {
                            "id": r.index,
                            "objective": r.objective,
                            "why": [str(c) for c in r.fired],
                            "measures": dict(zip(names, r.measures)),
                            "theta": dict(zip(labels, r.theta_repaired)),
                            "theta_raw": list(r.theta),
                            "repair_cost": r.repair_cost,
                            "seed": r.seed,
                        }
                        for r in failures
                    ],
                },
                sort_keys=False,
            ),
        )


def occupancy_shape(domain: Domain) -> tuple[int, int, int]:
    """One ``occupancy.f32`` record: the declared grids stacked (compile_spec admits only 32x32
    ones); of size zero for a task without grids."""
    return (len(domain.grids), 32, 32)
