"""``--algorithm auto``: spend the wall time on whatever finds the most per second, now.

Which algorithm finds the most failures per minute depends on the domain: where a scenario
simulates in milliseconds, training and searching a surrogate costs thousands of simulations and
model-free CMA-MAE wins; where it takes seconds, the surrogate's better-chosen proposals pay for
it. The paper says as much, and measurements on the bundled domains agree. ``auto`` does not
guess: it treats Random, MAP-Elites, CMA-MAE and SAS as the arms of a bandit and measures each
batch's *QD-score gained per wall second* (proposing and simulating it, on this machine, with
these workers). Every rate falls as the archive fills, so a rate measured early says little about
now: each batch's rate is divided by the *pace* of the search just before it (the rate of the
last :data:`PACE` batches, whatever proposed them), and arms are compared by that relative rate.
Every batch goes to the arm with the best recent relative rate, except that a losing arm is
tried again once the others have had :data:`PATIENCE` times its last batch's time, a patience
that doubles each time it loses again (so exploring costs a shrinking share of the run). All arms
share what is simulated: SAS trains on every evaluation, and the model-free arms share one
archive, which receives SAS's evaluations too.

SAS runs here with the schedule whose cost follows its data (incremental training, an inner loop
that stops when its archive stalls), and each outer iteration is given as much time as simulating
its batch takes, so that the surrogate never takes more than about half of the run.

Every batch's measurement and the choice behind it go to ``auto.json`` in the run directory, and
a summary per arm to ``run.json`` at the end.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, replace

import numpy as np

from hritest.domain import Domain
from hritest.records import EvaluationRecord
from hritest.search import algorithms, archives
from hritest.search.proposers import ModelFree, SearchView, SurrogateAssisted, SurrogateOptions

ARMS = ("random", "map_elites", "cma_mae", "sas")
PATIENCE = 4.0  # a losing arm waits this many times its last batch's seconds, doubled per loss
MAX_PATIENCE = 256.0
WINDOW = 2  # an arm's score: its mean relative rate over its last WINDOW batches
PACE = 3  # a batch's rate is relative to that of the PACE batches before it
STALL = 50  # SAS's inner loop stops when its archive has not grown in this many iterations
FILE = "auto.json"


@dataclass(frozen=True, kw_only=True)
class Batch:
    """One batch's measurement: what proposed it, why, and what it cost and gained."""

    batch: int
    arm: str
    reason: str
    evaluations: int
    seconds: float  # wall time to propose and simulate it
    gain: float  # QD-score gained
    rates: dict[str, float]  # every measured arm's score (relative rate) when the choice was made
    relative: float = 1.0  # its rate over the pace of the search before it

    @property
    def rate(self) -> float:
        return self.gain / max(self.seconds, 1e-9)


class Auto:
    """The proposer of ``--algorithm auto`` (see the module docstring)."""

    def __init__(self, domain: Domain, *, seed: int, options: SurrogateOptions) -> None:
        shared = archives.search_archive(domain, seed=seed)
        self.arms = {
            "random": ModelFree(algorithms.scheduler(domain, "random", shared, seed=seed)),
            "map_elites": ModelFree(algorithms.scheduler(domain, "map_elites", shared, seed=seed)),
            "cma_mae": ModelFree(algorithms.scheduler(domain, "cma_mae", shared, seed=seed)),
            "sas": SurrogateAssisted(
                domain,
                gradients=False,
                seed=seed,
                options=replace(
                    options,
                    training="incremental",
                    inner_stall=options.inner_stall or domain.spec.search.surrogate.inner_stall or STALL,
                ),
            ),
        }
        self.initial = domain.spec.search.surrogate.initial_evaluations
        self.history: list[Batch] = []
        self.patience = dict.fromkeys(ARMS, PATIENCE)
        self.choice: str | None = None
        self.reason = ""
        self.rates: dict[str, float] = {}
        self.asked: tuple[float, float] | None = None  # (time.monotonic(), QD-score) at the ask

    def __getstate__(self) -> dict:
        # A time.monotonic() of this process means nothing to the one that resumes: the batch
        # pending at a checkpoint is told, but not measured.
        return {**self.__dict__, "asked": None}

    def ask(self, search: SearchView) -> np.ndarray:
        self.choice, self.reason = self._choose(search)
        self.rates = {arm: round(self.score(arm), 4) for arm in ARMS if self._batches(arm)}
        self.asked = (time.monotonic(), search.qd_score)
        if self.choice == "sas":
            return self.arms["sas"].ask(search, seconds=self._simulation_seconds())
        return self.arms[self.choice].ask(search)

    def tell(self, search: SearchView, records: list[EvaluationRecord], solutions: np.ndarray) -> None:
        self.arms[self.choice].tell(search, records, solutions)
        if self.choice == "sas":  # the model-free arms share one archive: it learns of these too
            self.arms["cma_mae"].observe(search, records, solutions)
        if self.asked is not None:
            started, score = self.asked
            batch = Batch(
                batch=len(self.history) + 1,
                arm=self.choice,
                reason=self.reason,
                evaluations=len(records),
                seconds=round(time.monotonic() - started, 4),
                gain=search.qd_score - score,
                rates=self.rates,
            )
            before = self.history[-PACE:]
            pace = sum(b.gain for b in before) / max(sum(b.seconds for b in before), 1e-9) if before else batch.rate
            self.history.append(replace(batch, relative=batch.rate / pace if pace > 0 else float(batch.rate > 0)))
            self._update_patience()
        self.asked = None
        search.run_dir.write_text(FILE, json.dumps(self.summary() | {"batches": self._log()}, indent=1))

    # --- the choice ---------------------------------------------------------------------------

    def score(self, arm: str) -> float:
        """``arm``'s mean relative rate over its last :data:`WINDOW` batches: what decides."""
        recent = self._batches(arm)[-WINDOW:]
        return sum(b.relative for b in recent) / len(recent)

    def rate(self, arm: str) -> float:
        """QD-score gained per second by ``arm`` over its last :data:`WINDOW` batches."""
        recent = self._batches(arm)[-WINDOW:]
        return sum(b.gain for b in recent) / max(sum(b.seconds for b in recent), 1e-9)

    def _choose(self, search: SearchView) -> tuple[str, str]:
        surrogate_ready = search.evaluated >= self.initial
        spent = sum(b.seconds for b in self.history)
        for arm in ARMS:  # each arm once, SAS once there is data to train on
            if not self._batches(arm) and (arm != "sas" or surrogate_ready):
                # An arm never measured is a loser too: it waits until the run has spent
                # PATIENCE times what its first batch should cost (a CMA-MAE batch of slow scenarios
                # is not worth a short run's first minute).
                if self.history and spent < PATIENCE * self._expected_seconds(arm):
                    continue
                if arm == "sas" and not self._fits(search, arm):
                    continue
                return arm, "first measurement"
        measured = [arm for arm in ARMS if self._batches(arm)]
        best = max(measured, key=self.score)
        stale = [
            arm
            for arm in measured
            if arm != best and self._since(arm) >= self.patience[arm] * self._batches(arm)[-1].seconds
        ]
        for arm in sorted(stale, key=self._since, reverse=True):
            if self._fits(search, arm):
                return arm, f"re-measure (best: {best})"
        return best, "best rate"

    def _fits(self, search: SearchView, arm: str) -> bool:
        """Whether ``arm``'s last batch would end before the time limit (SAS's ask cannot be cut)."""
        last = self._batches(arm)
        seconds = last[-1].seconds if last else self._expected_seconds(arm)
        return arm != "sas" or seconds <= search.seconds_left

    def _expected_seconds(self, arm: str) -> float:
        """What a first batch of ``arm`` should take: its size at the recent seconds per evaluation
        (SAS: as long again for its training and inner loop)."""
        if arm == "sas":
            return 2 * self._simulation_seconds()
        return self.arms[arm].batch_size * self._seconds_per_evaluation()

    def _since(self, arm: str) -> float:
        """Seconds the other arms have had since ``arm``'s last batch."""
        last = self._batches(arm)[-1].batch
        return sum(b.seconds for b in self.history[last:])

    def _update_patience(self) -> None:
        """A re-measured arm that still loses waits twice as long; one that wins waits the least."""
        latest = self.history[-1]
        others = [self.score(arm) for arm in ARMS if arm != latest.arm and self._batches(arm)]
        if not others or latest.reason == "first measurement":
            return
        if self.score(latest.arm) >= max(others):
            self.patience[latest.arm] = PATIENCE
        elif latest.reason.startswith("re-measure"):
            self.patience[latest.arm] = min(2 * self.patience[latest.arm], MAX_PATIENCE)

    def _simulation_seconds(self) -> float:
        """What simulating a surrogate batch should take: its last size (at first, 100) at the
        recent seconds per evaluation."""
        sas = self._batches("sas")
        return (sas[-1].evaluations if sas else 100) * self._seconds_per_evaluation()

    def _seconds_per_evaluation(self) -> float:
        """The model-free arms' recent wall seconds per evaluation (proposing costs them next to
        nothing: this is what simulating one costs, with these workers)."""
        recent = [b for b in self.history if b.arm != "sas"][-2 * WINDOW :]
        if not recent:
            return math.inf
        return sum(b.seconds for b in recent) / max(sum(b.evaluations for b in recent), 1)

    def _batches(self, arm: str) -> list[Batch]:
        return [b for b in self.history if b.arm == arm]

    # --- what it tells the user ---------------------------------------------------------------

    def summary(self) -> dict:
        """Per arm: batches, evaluations, seconds and their share, QD-score gained, the recent rate."""
        total = sum(b.seconds for b in self.history) or 1.0
        return {
            "arms": {
                arm: {
                    "batches": len(done),
                    "evaluations": sum(b.evaluations for b in done),
                    "seconds": round(sum(b.seconds for b in done), 3),
                    "time_share": round(sum(b.seconds for b in done) / total, 4),
                    "qd_score_gained": round(sum(b.gain for b in done), 3),
                    "recent_rate": round(self.rate(arm), 4),
                    "score": round(self.score(arm), 4),
                }
                for arm in ARMS
                if (done := self._batches(arm))
            }
        }

    def _log(self) -> list[dict]:
        return [asdict(b) | {"rate": round(b.rate, 4), "relative": round(b.relative, 4)} for b in self.history]
