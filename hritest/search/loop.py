"""The search loop: ask a batch, evaluate it in parallel, tell the results, checkpoint.

One batch at a time, so a run is reproducible: evaluations stream back in any order, but are
told to the scheduler in the order they were asked. The state is checkpointed after every ask
and every tell, and each finished evaluation is appended to the run directory the moment it
arrives, so a killed run resumes from its last checkpoint and re-evaluates nothing it finished.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import yaml

from hritest.domain import Domain
from hritest.evaluate import Evaluation
from hritest.rundir import RunDirectory
from hritest.search import algorithms, archives
from hritest.search.executor import Evaluator, Job

ALGORITHMS = algorithms.MODEL_FREE


@dataclass(frozen=True)
class Snapshot:
    """Where a search stands, for progress displays."""

    evaluations: int
    budget: int
    summary: archives.Summary | None
    failures: int


def evaluation_seed(seed: int, index: int) -> int:
    """The seed of evaluation ``index``: independent of which worker runs it, or when."""
    return int(np.random.SeedSequence([seed, index]).generate_state(1)[0])


def record_of(job: Job, batch: int, evaluation: Evaluation) -> dict:
    """The JSON line of one evaluation (occupancy grids are stored apart)."""
    return {
        "index": job.index,
        "batch": batch,
        "status": evaluation.status,
        "failure": evaluation.failure,
        "objective": _number(evaluation.objective),
        "search_objective": _number(evaluation.search_objective),
        "measures": [_number(v) for v in evaluation.measures],
        "repair_cost": _number(evaluation.repair_cost),
        "regions": evaluation.regions,
        "theta": np.asarray(evaluation.theta).tolist(),
        "theta_repaired": np.asarray(evaluation.theta_repaired).tolist(),
        "metrics": {k: _number(v) for k, v in evaluation.metrics.items()},
        "seed": evaluation.seed,
        "seconds": round(evaluation.seconds, 6),
        "message": evaluation.message,
    }


def _number(value: float) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None


class Search:
    """A model-free QD search over a domain, writing into a run directory.

    Build with :meth:`new` or :meth:`resume`; then :meth:`run`.
    """

    def __init__(self, *, domain: Domain, run: RunDirectory, state: dict) -> None:
        self.domain, self.run_dir, self.state = domain, run, state
        self.records: dict[int, dict] = {r["index"]: r for r in run.evaluations()}
        self.occupancy_shape = (len(domain.task_cls.agents), 32, 32)

    @classmethod
    def new(cls, *, domain: Domain, run: RunDirectory, algorithm: str, budget: int, seed: int) -> Search:
        search_archive = archives.search_archive(domain, seed=seed)
        state = {
            "algorithm": algorithm,
            "budget": budget,
            "seed": seed,
            "scheduler": algorithms.scheduler(domain, algorithm, search_archive, seed=seed),
            "result": archives.result_archive(domain, seed=seed),
            "evaluations": 0,
            "batch": 0,
            "pending": None,
            "elapsed": 0.0,
            "progress": [],
        }
        run.save_checkpoint(state)
        return cls(domain=domain, run=run, state=state)

    @classmethod
    def resume(cls, *, domain: Domain, run: RunDirectory) -> Search:
        state = run.load_checkpoint()
        if state is None:
            from hritest.rundir import RunDirectoryError

            raise RunDirectoryError(f"{run.path} has no checkpoint.pkl; the run cannot be resumed")
        search = cls(domain=domain, run=run, state=state)
        # Keep only what the checkpoint knows of: the told evaluations and the pending batch's.
        pending = state["pending"]
        known = state["evaluations"] + (pending["count"] if pending else 0)
        keep = [r for r in run.evaluations() if r["index"] < known]
        run.truncate(len(keep), search.occupancy_shape)  # drops a torn line and its grids
        search.records = {r["index"]: r for r in keep}
        return search

    @property
    def done(self) -> bool:
        return self.state["evaluations"] >= self.state["budget"]

    def run(self, evaluator: Evaluator, progress: Callable[[Snapshot], None] = lambda s: None) -> None:
        """Runs batches until the budget is spent."""
        while not self.done:
            self.step(evaluator, progress)

    def step(self, evaluator: Evaluator, progress: Callable[[Snapshot], None]) -> None:
        """One batch: ask (unless a resumed batch is pending), evaluate what is missing, tell."""
        started = time.monotonic()
        state = self.state
        if state["pending"] is None:
            solutions = state["scheduler"].ask()
            state["batch"] += 1
            count = min(len(solutions), state["budget"] - state["evaluations"])
            state["pending"] = {"batch": state["batch"], "solutions": solutions, "first": state["evaluations"],
                                "count": count}
            self.run_dir.save_checkpoint(state)
        pending = state["pending"]
        first, count, batch = pending["first"], pending["count"], pending["batch"]
        jobs = [Job(first + i, pending["solutions"][i], evaluation_seed(state["seed"], first + i))
                for i in range(count) if first + i not in self.records]

        def finished(job: Job, evaluation: Evaluation) -> None:
            record = record_of(job, batch, evaluation)
            self.run_dir.append(record, evaluation.occupancy, self.occupancy_shape)
            self.records[job.index] = record
            progress(self.snapshot(extra=len([i for i in range(first, first + count) if i in self.records])))

        evaluator.run(jobs, finished)
        self._tell([self.records[first + i] for i in range(count)], pending["solutions"])
        state["evaluations"] += count
        state["pending"] = None
        state["elapsed"] += time.monotonic() - started
        summary = archives.Summary.of(state["result"], self.domain.spec.objective.range)
        failures = self.failures()
        state["progress"].append({
            "evaluations": state["evaluations"], "batch": batch, "wall_time": round(state["elapsed"], 3),
            "qd_score": summary.qd_score, "normalized_qd_score": summary.normalized_qd_score,
            "coverage": summary.coverage, "best": summary.best, "failures": len(failures),
        })
        self.run_dir.save_checkpoint(state)
        self.write_summaries(failures)
        progress(Snapshot(state["evaluations"], state["budget"], summary, len(failures)))

    def _tell(self, records: list[dict], solutions: np.ndarray) -> None:
        """Tells the scheduler (full batches only) and adds successes to the result archive."""
        domain, state = self.domain, self.state
        lo, hi = domain.spec.objective.range
        bad = lo - (hi - lo)  # below any threshold: ranked last, never an elite
        ok = [r["status"] == "ok" for r in records]
        measures = np.array([r["measures"] if good else [m.range[0] for m in domain.measures]
                             for r, good in zip(records, ok)], dtype=float).reshape(len(records), -1)
        if len(records) == len(solutions):
            objective = np.array([r["search_objective"] if good and r["search_objective"] is not None else bad
                                  for r, good in zip(records, ok)])
            regions = archives.region_measures(domain, [r["regions"] for r in records])
            state["scheduler"].tell(np.maximum(objective, bad), np.hstack([measures, regions]))
        if any(ok):
            good = np.flatnonzero(ok)
            state["result"].add(
                np.array([records[i]["theta_repaired"] for i in good]),
                np.array([records[i]["objective"] for i in good]),
                measures[good],
                evaluation=np.array([records[i]["index"] for i in good]),
            )

    def snapshot(self, extra: int = 0) -> Snapshot:
        return Snapshot(self.state["evaluations"] + extra, self.state["budget"], None, 0)

    def failures(self) -> list[dict]:
        """The result archive's elites that meet the failure condition, worst first."""
        data = self.state["result"].data(["evaluation", "objective"])
        found = [self.records[int(i)] for i in data["evaluation"] if self.records[int(i)]["failure"]]
        return sorted(found, key=lambda r: -r["objective"])

    def write_summaries(self, failures: list[dict]) -> None:
        names = [m.name for m in self.domain.measures]
        labels = self.domain.space.labels
        self.run_dir.write_csv("progress.csv", self.state["progress"])
        elites = sorted((self.records[int(i)] for i in self.state["result"].data("evaluation")),
                        key=lambda r: -r["objective"])
        self.run_dir.write_csv("archive.csv", [
            {"evaluation": r["index"], "objective": r["objective"], **dict(zip(names, r["measures"])),
             **dict(zip(labels, r["theta_repaired"])), "failure": r["failure"]}
            for r in elites
        ])
        self.run_dir.write_text("failures.yaml", yaml.safe_dump({
            "spec": self.run_dir.meta.get("spec_file"),
            "failure": self.domain.spec.failure,
            "failures": [
                {"id": r["index"], "objective": r["objective"], "measures": dict(zip(names, r["measures"])),
                 "theta": dict(zip(labels, r["theta_repaired"])), "theta_raw": r["theta"],
                 "repair_cost": r["repair_cost"], "seed": r["seed"]}
                for r in failures
            ],
        }, sort_keys=False))
