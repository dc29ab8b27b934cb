"""The search loop: ask a batch, evaluate it in parallel, tell the results, checkpoint.

One batch at a time, so a run is reproducible: evaluations stream back in any order, but are
told to the scheduler in the order they were asked. The state (a
:class:`~hritest.search.state.SearchState`) is checkpointed after every ask and every tell, and each
finished evaluation is appended to the run directory the moment it arrives, so a killed run resumes
from its last checkpoint and re-evaluates nothing it finished.

A proposer that can ask ahead (SAS / DSAS with ``pipeline``) is asked for the next batch on a
thread while the current batch simulates, from the batches told before it, so the workers need
not wait while it trains and searches its surrogate; that batch is checkpointed with the state
(``ahead``) and simulated next, so a pipelined run too resumes as if it had never stopped.
"""

from __future__ import annotations

import copy
import ctypes
import math
import signal
import threading
import time
import traceback
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, replace

import numpy as np
import yaml

from hritest import interrupt
from hritest.domain import Domain
from hritest.errors import HritestError
from hritest.interrupt import Interrupted
from hritest.records import Evaluation, EvaluationRecord, Status, rank_failures
from hritest.rundir import RunDirectory, RunDirectoryError
from hritest.search import algorithms, archives
from hritest.search.auto import Auto
from hritest.search.executor import Evaluator, Job
from hritest.search.proposers import ModelFree, SurrogateAssisted, SurrogateOptions
from hritest.search.state import PendingBatch, ProgressRow, SearchState, check_resumable, evaluation_seed, load_state
from hritest.search.training import GridRows, TrainingData

SURROGATE = ("sas", "dsas")
AUTO = "auto"
# progress.csv, archive.csv and failures.yaml are rewritten at most this often (and at the end):
# between batches the workers wait, so the loop does only what resuming needs (the checkpoint).
# A long run's summaries take longer to write: then at most every SUMMARY_SHARE of the time.
SUMMARY_SECONDS = 5.0
SUMMARY_SHARE = 0.02
ALGORITHMS = (*algorithms.MODEL_FREE, *SURROGATE, AUTO)
ERROR_LOG = "error.log"  # the traceback of a bug in hritest that stopped the search


class _Cancelled(BaseException):
    """Raised in an ask-ahead thread to stop it (see :meth:`_Ahead.cancel`)."""


class _AheadView:
    """The search as a proposer asking ahead sees it: the batches told so far, fixed when the ask
    starts, while the batch in flight adds records on the main thread."""

    def __init__(self, search: Search) -> None:
        self.search, self.domain, self.run_dir = search, search.domain, search.run_dir
        self.evaluated, self.qd_score = search.evaluated, search.qd_score
        self.seconds_per_evaluation = search.seconds_per_evaluation
        self.data = search.dataset(before=search.evaluated)
        self.result = copy.deepcopy(search.state.result)

    @property
    def seconds_left(self) -> float:
        return self.search.seconds_left

    def dataset(self) -> tuple[np.ndarray, np.ndarray | GridRows, np.ndarray]:
        return self.data

    def elite_objectives(self, measures: np.ndarray) -> np.ndarray:
        return archives.elite_objectives(self.result, measures, empty=self.domain.spec.objective.range[0])

    def phase(self, name: str) -> None:
        self.search.ahead_phase = name  # shown beside "simulating" by the next snapshot


class _Ahead:
    """The next batch's ask, on a thread while the current batch simulates."""

    def __init__(self, search: Search) -> None:
        view, proposer = _AheadView(search), search.state.proposer
        self.solutions: np.ndarray | None = None
        self.error: BaseException | None = None

        def ask() -> None:
            try:
                self.solutions = proposer.ask(view)
            except BaseException as exc:  # re-raised on the main thread by result()
                self.error = exc

        self.thread = threading.Thread(target=ask, name="hritest-ask-ahead", daemon=True)
        self.thread.start()

    def result(self) -> np.ndarray:
        """The batch asked, once the ask ends; what the ask raised, raised here."""
        self.thread.join()
        if self.error is not None:
            raise self.error
        return self.solutions

    def cancel(self) -> None:
        """Stops the ask at its next Python instruction (training and the inner loop run many
        short steps), for a search stopped by an interrupt or an error: its proposer is abandoned
        with the search, never checkpointed half-changed."""
        if self.thread.is_alive():
            ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(self.thread.ident), ctypes.py_object(_Cancelled))
        self.thread.join(timeout=30)


@dataclass(frozen=True)
class Snapshot:
    """Where a search stands, for progress displays.

    ``summary`` and ``failures`` (elites that meet the failure condition) are as of the last
    batch; ``failed`` counts the evaluations that did not complete; ``phase`` says what the
    search is doing: ``proposing`` a batch (for SAS/DSAS, ``training`` the surrogate, then its
    ``inner loop``) or ``simulating`` one (pipelined, ``simulating + training`` the surrogate for
    the next batch, and so on); ``proposer`` is what proposes it (the algorithm, or
    the one ``auto`` chose). ``budget`` is ``None`` without an evaluation budget, ``deadline``
    (a ``time.monotonic()`` value) ``None`` without a time limit.
    """

    evaluations: int
    budget: int | None
    summary: archives.Summary | None
    failures: int
    failed: int = 0
    phase: str = "simulating"
    proposer: str = ""
    deadline: float | None = None


class Search:
    """A QD search over a domain, writing into a run directory.

    Build with :meth:`new` or :meth:`resume`; then :meth:`run`. Every evaluation goes to the run
    directory as it finishes; the search keeps in memory only the records of its result
    archive's elites and of the batch in flight, counts of the rest, and, for a surrogate, the
    compact :class:`~hritest.search.training.TrainingData`: its memory does not grow with the run.
    """

    def __init__(
        self, *, domain: Domain, run: RunDirectory, state: SearchState, records: Iterable[EvaluationRecord]
    ) -> None:
        self.domain, self.run_dir, self.state = domain, run, state
        self.occupancy_shape = occupancy_shape(domain)
        self.kept: dict[int, EvaluationRecord] = {}  # the result archive's elites and the batch in flight
        self.statuses: Counter[str] = Counter()  # of every evaluation written
        self.training = (
            TrainingData(dim=domain.space.dim, outputs=1 + len(domain.measures))
            if state.algorithm in (*SURROGATE, AUTO)
            else None
        )
        elites = {int(i) for i in state.result.data("evaluation")}
        batch = state.pending.first if state.pending else math.inf
        for record in records:
            self._note(record)
            if record.index in elites or record.index >= batch:
                self.kept[record.index] = record
        self.summarised = -math.inf
        self.summary_every = SUMMARY_SECONDS
        self.clock = (time.monotonic(), state.elapsed)  # (when, the run's wall time then)
        self.last = Snapshot(state.evaluations, state.budget, None, 0, self.failed)
        self.deadline: float | None = None
        self.cut: ProgressRow | None = None  # where a batch the deadline cut short got to
        self.ahead_phase = ""  # what an ask ahead of the batch in flight is doing
        self.added: dict[int, float] = {}  # what each evaluation of the last batch added to the QD-score
        self.progress: Callable[[Snapshot], None] = lambda s: None

    def _note(self, record: EvaluationRecord) -> None:
        """Counts a record written to the run directory (its line is the next), and keeps what a
        surrogate learns from it."""
        if self.training is not None and record.ok:
            lo, hi = self.domain.spec.objective.range
            self.training.append(
                index=record.index,
                line=self.written,
                theta=record.theta,
                targets=[record.search_objective / (hi - lo), *record.measures],
            )
        self.statuses[record.status.value] += 1

    @property
    def written(self) -> int:
        """Evaluations in the run directory."""
        return self.statuses.total()

    @property
    def failed(self) -> int:
        """Evaluations that did not complete."""
        return self.written - self.statuses[Status.OK.value]

    @classmethod
    def new(
        cls,
        *,
        domain: Domain,
        run: RunDirectory,
        algorithm: str,
        budget: int | None,
        seed: int,
        options: SurrogateOptions | None = None,
    ) -> Search:
        options = options or SurrogateOptions()
        if algorithm == AUTO:
            proposer = Auto(domain, seed=seed, options=options)
        elif algorithm in SURROGATE:
            proposer = SurrogateAssisted(domain, gradients=algorithm == "dsas", seed=seed, options=options)
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
        shape = occupancy_shape(domain)
        keep = check_resumable(state, run=run, records=run.iter_evaluations(), dim=domain.space.dim, grid_shape=shape)
        run.truncate(keep, shape)
        return cls(domain=domain, run=run, state=state, records=run.iter_evaluations())

    @property
    def evaluated(self) -> int:
        """Evaluations told so far."""
        return self.state.evaluations

    @property
    def done(self) -> bool:
        """Whether the evaluation budget is spent."""
        return self.state.budget is not None and self.state.evaluations >= self.state.budget

    @property
    def out_of_time(self) -> bool:
        return self.deadline is not None and time.monotonic() >= self.deadline

    @property
    def seconds_left(self) -> float:
        """Until the time limit (infinite without one)."""
        return math.inf if self.deadline is None else self.deadline - time.monotonic()

    @property
    def seconds_per_evaluation(self) -> float | None:
        """What the last batch told took besides its proposing (simulating it, storing what came
        back, the checkpoint) over its evaluations (None before the first; a batch cut short to
        nothing by a time limit is skipped)."""
        rows = self.state.progress
        for k in range(len(rows) - 1, -1, -1):
            evaluations, wall_time = (rows[k - 1].evaluations, rows[k - 1].wall_time) if k else (0, 0.0)
            if evaluated := rows[k].evaluations - evaluations:
                return max(rows[k].wall_time - wall_time - rows[k].propose_seconds, 0.0) / evaluated
        return None

    @property
    def qd_score(self) -> float:
        """The result archive's QD-score now."""
        return archives.Summary.of(self.state.result, self.domain.spec.objective.range).qd_score

    @property
    def proposer_name(self) -> str:
        """What proposes the batches now: the algorithm, or the one that ``auto`` chose."""
        return getattr(self.state.proposer, "choice", None) or self.state.algorithm

    def phase(self, name: str) -> None:
        """Tells the progress display what the search is doing now (a proposer calls it)."""
        self.progress(replace(self.snapshot(), phase=name))

    def run(
        self,
        evaluator: Evaluator,
        progress: Callable[[Snapshot], None] = lambda s: None,
        *,
        deadline: float | None = None,
    ) -> None:
        """Runs batches until the budget is spent or ``deadline`` (a ``time.monotonic()`` value) passes.

        At the deadline, the batch being simulated ends with the evaluations already started, and
        the run stops as after a full batch: nothing is lost, and ``--resume`` continues it.

        Raises:
            Interrupted: on SIGINT or SIGTERM (see :mod:`hritest.interrupt`), naming the run
                directory, whose files are whole: ``--resume`` continues the run.
            Exception: a bug in hritest, its traceback written to ``error.log`` in the run
                directory, whose path the exception holds as ``traceback_file``.
        """
        self.deadline, self.progress = deadline, progress
        if self.state.algorithm not in ("random", "map_elites"):  # the others run CMA-ES
            algorithms.compile_cma_es()
        self.clock = (time.monotonic(), self.state.elapsed)
        try:
            while not (self.done or self.out_of_time):
                self.step(evaluator)
            self.write_summaries(self.failures())
            self.progress(replace(self.snapshot(), evaluations=self.written))
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

    def step(self, evaluator: Evaluator) -> None:
        """One batch: ask (unless a resumed batch is pending), evaluate what is missing, tell.

        A batch the deadline cuts short stays pending, as a Ctrl-C leaves it: its evaluations are
        in the result archive and the summaries, and a resume evaluates the rest and tells it whole,
        so that a run stopped by time limits and resumed is the run that never stopped.
        """
        started = time.monotonic()
        state = self.state
        proposing = 0.0
        if state.pending is None:
            if state.ahead is not None:  # asked while the last batch simulated
                solutions = state.ahead
            else:
                self.phase("proposing")
                solutions = state.proposer.ask(self)
                proposing = time.monotonic() - started
            left = math.inf if state.budget is None else state.budget - state.evaluations
            count = int(min(len(solutions), left))
            pending = PendingBatch(batch=state.batch + 1, solutions=solutions, first=state.evaluations, count=count)
            self.state = state = replace(state, batch=pending.batch, pending=pending, ahead=None)
            with interrupt.deferred():
                self.run_dir.save_checkpoint(state)
        pending = state.pending
        first, count, batch = pending.first, pending.count, pending.batch
        jobs = [
            Job(first + i, pending.solutions[i], evaluation_seed(state.seed, first + i))
            for i in range(count)
            if first + i not in self.kept
        ]

        done = [count - len(jobs)]  # of this batch, finished before (a resumed batch) or now

        def finished(job: Job, evaluation: Evaluation) -> None:
            record = EvaluationRecord.of(evaluation, index=job.index, batch=batch)
            with interrupt.deferred():
                self.run_dir.append(record, evaluation.occupancy, self.occupancy_shape)
                self._note(record)
                self.kept[job.index] = record
            done[0] += 1
            self.progress(self.snapshot(extra=done[0]))

        last = state.budget is not None and first + count >= state.budget
        can_ask_ahead = getattr(state.proposer, "can_ask_ahead", lambda search: False)
        ahead = _Ahead(self) if state.ahead is None and not last and can_ask_ahead(self) else None
        try:
            self.progress(self.snapshot(extra=done[0]))
            evaluator.run(jobs, finished, deadline=self.deadline)
            if ahead is not None:  # proposing costs the run only what it takes beyond the simulation
                waiting = time.monotonic()
                self.state = state = replace(state, ahead=ahead.result())
                proposing, self.ahead_phase = time.monotonic() - waiting, ""
        except BaseException:
            if ahead is not None:
                ahead.cancel()
            raise
        records = [self.kept[first + i] for i in range(count) if first + i in self.kept]
        # Told again when a resume completes the batch: adding an elite twice changes nothing.
        self._add_to_result(records)
        summary = archives.Summary.of(state.result, self.domain.spec.objective.range)
        failures = self.failures()
        elapsed = self.wall_time
        row = ProgressRow(
            evaluations=state.evaluations + len(records),
            batch=batch,
            wall_time=round(elapsed, 3),
            qd_score=summary.qd_score,
            normalized_qd_score=summary.normalized_qd_score,
            coverage=summary.coverage,
            best=summary.best,
            failures=len(failures),
            proposer=self.proposer_name,
            propose_seconds=round(proposing, 3),
        )
        if len(records) < count:  # the deadline cut the batch: it stays pending, for --resume to finish
            with interrupt.deferred():
                self.state = replace(state, elapsed=elapsed)
                self.run_dir.save_checkpoint(self.state)
            self.cut = row
            return
        state.proposer.tell(self, records, pending.solutions)
        self.kept = {int(i): self.kept[int(i)] for i in state.result.data("evaluation")}
        with interrupt.deferred():
            self.state = state = replace(
                state, evaluations=row.evaluations, pending=None, elapsed=elapsed, progress=(*state.progress, row)
            )
            self.run_dir.save_checkpoint(state)
        if time.monotonic() - self.summarised >= self.summary_every:
            self.write_summaries(failures)
        self.last = replace(self.last, evaluations=state.evaluations, summary=summary, failures=len(failures))
        self.progress(self.snapshot())

    def _add_to_result(self, records: list[EvaluationRecord]) -> None:
        """Adds the successful evaluations to the result archive with their raw objective, and
        keeps what each added to its QD-score, for :meth:`gains`."""
        good = [r for r in records if r.ok]
        self.added = {}
        if good:
            added = self.state.result.add(
                np.array([r.theta_repaired for r in good]),
                np.array([r.objective for r in good]),
                np.array([r.measures for r in good]),
                evaluation=np.array([r.index for r in good]),
            )
            # ribs' value: the improvement on the elite replaced, or the objective where a cell was
            # new (over 0, where the QD-score counts it over the objective range's low end)
            lo = self.domain.spec.objective.range[0]
            gain = np.select([added["status"] == 2, added["status"] == 1], [added["value"] - lo, added["value"]], 0.0)
            self.added = {r.index: float(g) for r, g in zip(good, gain, strict=True)}

    def gains(self, records: list[EvaluationRecord]) -> np.ndarray:
        """What each of ``records``, of the batch being told, added to the result archive's
        QD-score: its objective over the elite it replaced, or over the objective range's low end
        in a cell it filled; 0 where it added nothing or did not complete. (Two that fill the same
        cell in one batch both count.)"""
        return np.array([self.added.get(r.index, 0.0) for r in records], dtype=float)

    def dataset(self, before: int | None = None) -> tuple[np.ndarray, np.ndarray | GridRows, np.ndarray]:
        """Training data from every successful evaluation (with ``before``, of those of a lower
        index): raw theta, occupancy grids, targets.

        Targets are the regularised objective over the objective's range, then the measures. Rows
        are in evaluation order, not in the order the workers finished them (the files' order),
        so that training, and so the run, is the same whatever the number of workers. The grids
        are read from the run directory when indexed (:class:`~hritest.search.training.GridRows`).
        """
        theta, targets, lines = self.training.in_evaluation_order(before)
        if math.prod(self.occupancy_shape) == 0:
            return theta, np.zeros((len(theta), *self.occupancy_shape), np.float32), targets
        return theta, GridRows(self.run_dir.occupancy(self.occupancy_shape), lines), targets

    def elite_objectives(self, measures: np.ndarray) -> np.ndarray:
        """The result archive's objective in the cells of ``measures``, the objective range's low
        end where a cell is empty (what SAS's selection weighs its predictions against)."""
        return archives.elite_objectives(self.state.result, measures, empty=self.domain.spec.objective.range[0])

    def snapshot(self, extra: int = 0) -> Snapshot:
        """The last batch's snapshot, with ``extra`` evaluations of the current one finished."""
        return replace(
            self.last,
            evaluations=self.state.evaluations + extra,
            failed=self.failed,
            phase=f"simulating + {self.ahead_phase}" if self.ahead_phase else "simulating",
            proposer=self.proposer_name,
            deadline=self.deadline,
        )

    def failures(self) -> list[EvaluationRecord]:
        """The result archive's elites that meet the failure condition, worst first."""
        return rank_failures(self.kept[int(i)] for i in self.state.result.data("evaluation"))

    @property
    def wall_time(self) -> float:
        """The run's wall time: its earlier sessions' and this one's, everything included."""
        since, before = self.clock
        return before + time.monotonic() - since

    def write_summaries(self, failures: list[EvaluationRecord]) -> None:
        started = time.monotonic()
        self._write_summaries(failures)
        self.summarised = time.monotonic()
        self.summary_every = max(SUMMARY_SECONDS, (self.summarised - started) / SUMMARY_SHARE)

    def _write_summaries(self, failures: list[EvaluationRecord]) -> None:
        names = [m.name for m in self.domain.measures]
        labels = self.domain.space.labels
        cut = [asdict(self.cut)] if self.cut else []
        self.run_dir.write_csv("progress.csv", self.state.progress_rows() + cut)
        elites = sorted(
            (self.kept[int(i)] for i in self.state.result.data("evaluation")),
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
            yaml.dump(
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
                Dumper=getattr(yaml, "CSafeDumper", yaml.SafeDumper),  # libyaml's, when PyYAML has it: twice as fast
            ),
        )


def occupancy_shape(domain: Domain) -> tuple[int, int, int]:
    """One ``occupancy.f32`` record: the declared grids stacked (compile_spec admits only 32x32
    ones); of size zero for a task without grids."""
    return (len(domain.grids), 32, 32)
