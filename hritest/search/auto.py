"""``--algorithm auto``: spend the wall time on whatever finds the most per second, now.

Which algorithm finds the most failures per minute depends on the domain: where a scenario
simulates in milliseconds, training and searching a surrogate costs thousands of simulations and
model-free CMA-MAE wins; where it takes seconds, the surrogate's better-chosen proposals pay for
it. The paper says as much, and measurements on the bundled domains agree. ``auto`` does not
guess: it treats Random, MAP-Elites, CMA-MAE and SAS as the arms of a bandit and measures the
*QD-score gained per wall second* of each (proposing and simulating, on this machine, with these
workers).

* **Stints, not batches.** An arm runs for a stint of at least a second and 3 % of the run so
  far (and at least one of its batches; a first stint of CMA-MAE, :data:`WARMUP`): a
  20-scenario batch that fills one cell more or less than the last says nothing. When CMA-MAE joins a search that
  others began, or comes back after they went on for :data:`PATIENCE` times its last stint, its
  emitters start afresh at the search's elites, not at the spec's ``x0`` or where they stopped.
* **Relative rates.** Every rate falls as the archive fills, so a rate measured a minute ago says
  little about now: a stint's gain is compared with what the search's *pace* around it (its rate
  over the :data:`PACE` quanta of time before the stint and, once the search has gone on as long,
  after it) would have gained in the same seconds, and an arm's score is that ratio over its last
  :data:`WINDOW` stints; SAS's over those it began on at least :data:`FRESH` of the data its
  latest began on, since its surrogate learns from every evaluation and a stint on far less data
  understates what it does now.
* **Exploring costs a bounded share.** Each stint goes to the arm with the best score (the best
  model-free one when SAS's batch, which cannot be cut, would not end before the limit), except
  that arms never measured are measured first, one at a time and the cheapest first, and a losing
  arm again once the others have had :data:`PATIENCE` times its last stint (a patience that
  doubles each time it loses again); both only while measuring arms that did not come out of it
  the best has taken at most :data:`EXPLORE` of the run. With a time limit, that share is of the
  limit, from the start: the sooner the best arm is known, the longer it runs.
* **An arm that learns is measured again as it learns.** SAS's surrogate gains from every
  evaluation, so a losing SAS is not the SAS of a minute later: while its score is at least
  :data:`FLOOR` of the best arm's and its inner loop has the time to use what the surrogate
  learns, it is measured again each time the others have had :data:`PATIENCE` times its last
  stint (a patience that does not double), out of a share of its own as large as the exploring
  one. Alone on collaboration, SAS gains half the pace in its first two minutes and passes
  MAP-Elites after five; measured once early and then as a losing arm, auto gave it a few
  percent of the time.

All arms share what is simulated: SAS trains on every evaluation, and the model-free arms share one
archive, which receives SAS's evaluations too. SAS runs here with the schedule whose cost follows
its data (incremental training, an inner loop that stops when its archive stalls, and the
surrogate elites predicted to add the most chosen for simulation), and each outer iteration's
surrogate work is cut to the spec's ``time_share`` of it, from what simulating its batch takes
(the specs' default, a fifth, where the spec never cuts: the paper's specs).

Every batch's measurement and the choice behind it go to ``auto.json`` in the run directory (at
each stint's end), and a summary per arm to ``run.json`` at the end.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, replace

import numpy as np

from hritest.domain import Domain
from hritest.records import EvaluationRecord
from hritest.rundir import RunDirectory
from hritest.search import algorithms, archives
from hritest.search.proposers import ModelFree, SearchView, SurrogateAssisted, SurrogateOptions
from hritest.spec.models import SurrogateSettings

ARMS = ("random", "map_elites", "cma_mae", "sas")
PATIENCE = 4.0  # a losing arm waits this many times its last stint's seconds, doubled per loss
MAX_PATIENCE = 256.0
EXPLORE = 0.08  # at most this share of the run measures arms that do not come out best
MIN_STINT = 1.0  # seconds: a stint lasts at least this long (and one batch of its arm)
STINT_SHARE = 0.03  # and this share of the run so far
WARMUP = 3  # the first stint of an arm that adapts lasts at least this many of its batches
ADAPTING = ("cma_mae",)  # its batches depend on its own earlier ones (CMA-ES's step size and covariance)
WINDOW = 2  # an arm's score: its gain over the pace's, in its last WINDOW stints
# Scored by its stints begun on at least FRESH of the data its latest began on: the surrogate
# learns from every evaluation, the other arms' too, so a stint on far less data understates it
# (on collaboration, a first measurement at 10 s, on 120 evaluations, at 0.37 of the pace kept
# SAS's score under MAP-Elites' for the 8 minutes after a stint at 1.02). Not by its latest alone:
# its stints are single batches whose gains range from 0.35 to 1.9 of the pace, and one bad batch
# handed the lead back for minutes. For the same reason it needs no warm-up: its first batch is
# what any of its batches would be on the same data.
LEARNING = ("sas",)
FRESH = 0.5  # SAS is scored by its stints begun on at least this share of the data its latest began on
PACE = 3  # the pace: the search's rate over the last PACE stints' worth of time
# SAS's inner loop stall where the spec has none (the paper's specs): the default
STALL = SurrogateSettings.model_fields["inner_stall"].default
# and its surrogate's share where the spec never cuts (the paper's specs): the specs' default
SHARE = SurrogateSettings.model_fields["time_share"].default
FLOOR = 0.25  # a learning arm is measured again while its score is at least this share of the best's
FILE = "auto.json"
BEST = "best rate"  # the reason for a stint of the arm with the best score


def sas_options(options: SurrogateOptions, spec: SurrogateSettings) -> SurrogateOptions:
    """What auto's SAS arm runs with, whatever the spec's ``search.surrogate`` and ``options`` say
    of the schedule: incremental training, an inner loop that stops when it stalls (the spec's
    stall, or the default), the selection by predicted gain, screened, and the surrogate's work always cut
    (a spec that never cuts it, as the paper's, gets the default share, or its SAS would take most
    of a slow domain's stints). ``run.json`` records these, not the spec's."""
    settings = options.applied_to(spec)
    return replace(
        options,
        training="incremental",
        inner_stall=settings.inner_stall or STALL,
        time_share=settings.time_share if settings.time_share < 1 else SHARE,
        selection="gain",
        screen=True,
    )


@dataclass(frozen=True, kw_only=True)
class Batch:
    """One batch's measurement: what proposed it, in which stint, why, and what it cost and gained."""

    batch: int
    stint: int
    arm: str
    reason: str
    evaluations: int
    seconds: float  # wall time to propose and simulate it
    gain: float  # QD-score gained
    pace: float = 0.0  # the search's QD-score per second over the time before its stint
    rates: dict[str, float]  # every measured arm's score when its stint began

    @property
    def rate(self) -> float:
        return self.gain / max(self.seconds, 1e-9)

    @property
    def relative(self) -> float:
        """Its gain over what the pace before its stint would have gained in its seconds."""
        return _ratio(self.gain, self.pace * self.seconds)


class Auto:
    """The proposer of ``--algorithm auto`` (see the module docstring)."""

    def __init__(self, domain: Domain, *, seed: int, options: SurrogateOptions) -> None:
        shared = archives.search_archive(domain, seed=seed)
        self.seed, self.shared = seed, shared
        sas = sas_options(options, domain.spec.search.surrogate)
        self.share = sas.time_share
        self.arms = {
            "random": ModelFree(algorithms.scheduler(domain, "random", shared, seed=seed)),
            "map_elites": ModelFree(algorithms.scheduler(domain, "map_elites", shared, seed=seed)),
            "cma_mae": ModelFree(algorithms.scheduler(domain, "cma_mae", shared, seed=seed)),
            "sas": SurrogateAssisted(
                domain,
                gradients=False,
                seed=seed,
                options=sas,
            ),
        }
        self.initial = domain.spec.search.surrogate.initial_evaluations
        self.history: list[Batch] = []
        self.patience = dict.fromkeys(ARMS, PATIENCE)
        self.choice: str | None = None
        self.reason = ""
        self.stint = -1
        self.spent = 0.0  # seconds of every batch so far
        self.stint_seconds = 0.0  # of the current stint's batches
        self.stint_batches = 0
        self.stint_pace = 0.0  # the search's pace before the current stint
        self.rates: dict[str, float] = {}
        self.asked: tuple[float, float] | None = None  # (time.monotonic(), QD-score) at the ask

    def __getstate__(self) -> dict:
        # A time.monotonic() of this process means nothing to the one that resumes: the batch
        # pending at a checkpoint is told, but not measured.
        return {**self.__dict__, "asked": None}

    def __setstate__(self, state: dict) -> None:
        # Checkpoints from before the share gave SAS as long as simulating its batch took: 0.5.
        self.__dict__ = {"share": 0.5, **state}
        self.arms["sas"].time_share = self.share

    def ask(self, search: SearchView) -> np.ndarray:
        if not self._continues(search):
            if self.history:
                self._end_stint()
                self.write_log(search.run_dir)
            self.choice, self.reason = self._choose(search)
            self.stint += 1
            self.stint_seconds, self.stint_batches = 0.0, 0
            self.stint_pace = self._pace(len(self.history), before=True)
            if self.choice == "cma_mae" and (not self.reason.startswith(BEST) or self._stale("cma_mae")):
                self._start_cma_mae(search.domain)
            self.rates = {arm: round(self.score(arm), 4) for arm in ARMS if self._batches(arm)}
        self.asked = (time.monotonic(), search.qd_score)
        if self.choice == "sas":
            return self.arms["sas"].ask(search, per_evaluation=self._seconds_per_evaluation())
        return self.arms[self.choice].ask(search)

    def tell(self, search: SearchView, records: list[EvaluationRecord], solutions: np.ndarray) -> None:
        self.arms[self.choice].tell(search, records, solutions)
        if self.choice == "sas":  # the model-free arms share one archive: it learns of these too
            self.arms["random"].observe(search, records, solutions)
        if self.asked is not None:
            started, score = self.asked
            seconds = time.monotonic() - started
            self.spent += seconds
            self.stint_seconds += seconds
            self.stint_batches += 1
            self.history.append(
                Batch(
                    batch=len(self.history) + 1,
                    stint=self.stint,
                    arm=self.choice,
                    reason=self.reason,
                    evaluations=len(records),
                    seconds=round(seconds, 4),
                    gain=search.qd_score - score,
                    pace=self.stint_pace,
                    rates=self.rates,
                )
            )
        self.asked = None

    def write_log(self, run_dir: RunDirectory) -> dict:
        """Writes every batch's measurement and choice to ``auto.json`` (at each stint's end and the
        run's: rewriting it after every batch would cost a long run more than its choices); returns
        the summary per arm."""
        summary = self.summary()
        run_dir.write_text(FILE, json.dumps(summary | {"batches": self._log()}, indent=1))
        return summary

    # --- the choice ---------------------------------------------------------------------------

    def score(self, arm: str) -> float:
        """``arm``'s gain in the stints that score it (:meth:`_scoring`) over what the search's
        pace would have gained in their seconds: what decides. The pace of a stint is that before
        it, or, once the search has gone on for as long, the geometric mean of the paces before
        and after it: rates fall fast early on, and a stint compared with the pace before it alone
        would look worse the longer it lasted."""
        gain = expected = 0.0
        for stint in self._scoring(arm):
            before = stint[0].pace
            after = self._pace(stint[-1].batch, before=False)
            pace = math.sqrt(before * after) if after is not None and before > 0 and after > 0 else before
            gain += sum(b.gain for b in stint)
            expected += pace * sum(b.seconds for b in stint)
        return _ratio(gain, expected)

    def rate(self, arm: str) -> float:
        """QD-score gained per second by ``arm`` in the stints that score it."""
        recent = [b for stint in self._scoring(arm) for b in stint]
        return sum(b.gain for b in recent) / max(sum(b.seconds for b in recent), 1e-9)

    def _scoring(self, arm: str) -> list[list[Batch]]:
        """The stints that score ``arm``: its last :data:`WINDOW`, or for an arm that learns
        (:data:`LEARNING`) those begun on at least :data:`FRESH` of the evaluations its latest
        began on. The run's first stint only while its arm has no other (it has no pace before it:
        counted, its gain against no expected gain made Random's score 4 to 6 after a one-second
        re-measurement)."""
        stints = [s for s in self._stints(arm) if s[0].stint > 0] or self._stints(arm)[:1]
        if arm not in LEARNING:
            return stints[-WINDOW:]
        done = np.cumsum([0] + [b.evaluations for b in self.history])  # evaluated before each batch
        began = [done[s[0].batch - 1] for s in stints]
        return [s for s, data in zip(stints, began, strict=True) if data >= FRESH * began[-1]]

    def quantum(self) -> float:
        """How long a stint lasts at least: :data:`MIN_STINT`, and :data:`STINT_SHARE` of the run
        so far (and one batch of its arm)."""
        return max(MIN_STINT, STINT_SHARE * self.spent)

    def _continues(self, search: SearchView) -> bool:
        """Whether the current stint goes on: it has lasted less than a quantum, or is a first
        measurement of fewer than :data:`WARMUP` batches of an arm that adapts (CMA-ES over its
        generations). Random's and MAP-Elites' batches depend on the archive only, and SAS's on
        the data, so their first one is like the next: where a batch takes half a minute,
        warming them up took Random's first stint 40 % of a 5-minute run, and left MAP-Elites
        unmeasured (collaboration on a slow machine); three SAS batches measured at 10 s took
        42 s of collaboration's 72 s of exploring."""
        if self.stint_batches == 0 or not self._fits(search, self.choice):
            return False
        warming = self.reason == "first measurement" and self.choice in ADAPTING and self.stint_batches < WARMUP
        return warming or self.stint_seconds < self.quantum()

    def _start_cma_mae(self, domain: Domain) -> None:
        """CMA-MAE joins a search that others began, or comes back to one that others went on
        with: its emitters start afresh at elites the search has found, one each, rather than all
        at the spec's ``x0`` or where they stopped (a region the search has since filled: resumed,
        a teleoperation run's re-measurements gained a quarter of the search's pace or less)."""
        emitters = domain.spec.search.emitter.emitters
        starts = self.shared.sample_elites(emitters)["solution"] if not self.shared.empty else None
        self.arms["cma_mae"] = ModelFree(
            algorithms.scheduler(domain, "cma_mae", self.shared, seed=self.seed + self.stint, starts=starts)
        )

    def _choose(self, search: SearchView) -> tuple[str, str]:
        if not self.history:
            return ARMS[0], "first measurement"
        spent, explored, learnt = self.spent, self._explored(), self._explored(learning=True)
        # With a time limit, exploring may take its share of the whole run from the start: the
        # sooner the best arm is known, the longer it runs.
        horizon = spent + (search.seconds_left if math.isfinite(search.seconds_left) else 0.0)
        measured = [arm for arm in ARMS if self._batches(arm)]
        best = max(measured, key=self.score)
        # Arms never measured go first, the cheapest first stint first (SAS's, once there are data
        # to train it on): measured last, SAS was never measured in 15 minutes of collaboration,
        # where CMA-MAE's first stint (87 s) spent the exploring share before SAS's (~30 s) came up.
        unmeasured = sorted(
            (arm for arm in ARMS if arm not in measured and (arm != "sas" or search.evaluated >= self.initial)),
            key=self._expected_seconds,
        )
        stale = [
            (arm, f"re-measure (best: {best})")
            for arm in sorted(measured, key=self._since, reverse=True)
            if arm != best and self._since(arm) >= self.patience[arm] * self._last_stint_seconds(arm)
        ]
        # An arm that learns, measured again while it is not far behind, out of a share of its own.
        learning = [
            (arm, f"keeps learning (best: {best})")
            for arm in LEARNING
            if arm in measured
            and arm != best
            and self._learns(arm)
            and self.score(arm) >= FLOOR * self.score(best)
            and self._since(arm) >= PATIENCE * self._last_stint_seconds(arm)
        ]
        # Measured in that order, the first that its share allows.
        candidates = [(arm, "first measurement") for arm in unmeasured] + learning + stale
        for arm, reason in candidates:
            cost = self._expected_seconds(arm)
            taken = learnt if reason.startswith("keeps learning") else explored
            if taken + cost <= EXPLORE * max(horizon, spent + cost) and self._fits(search, arm):
                return arm, reason
        if self._fits(search, best):
            return best, BEST
        # SAS's batch cannot be cut, and one the limit cuts is simulated for nothing: the seconds
        # left go to the best arm whose batch keeps what it finished (a 5-minute collaboration I
        # run stopped at 294 s with SAS the best, after an inner loop whose batch had no time left).
        return max((arm for arm in measured if self._fits(search, arm)), key=self.score), f"{BEST} in the time left"

    def _learns(self, arm: str) -> bool:
        """Whether more data can lift ``arm``: SAS, while one of its inner loops has had the time
        for as many iterations as it takes to stall (or for all of them). An inner loop that its
        share of the time always cuts shorter is held back by that time, not by what its
        surrogate knows: on teleoperation, whose scenarios take milliseconds, its rounds ran 2 to
        10 iterations and its stints kept learning at 0.3-0.9 of the pace for 13 % of a 5-minute
        run; on collaboration I, 59 to 97 iterations a round, against a stall of 50. Its first
        round does not count (it pays for the process's warm-up: 24 to 68 iterations on
        collaboration I), and until it has had another it gets the benefit of the doubt."""
        if arm not in LEARNING:
            return False
        sas = self.arms["sas"]
        later = [fit["inner_iterations"] for fit in sas.fits[1:]]
        return not later or max(later) >= min(sas.stall or sas.iterations, sas.iterations)

    def _explored(self, *, learning: bool = False) -> float:
        """Seconds spent measuring arms that did not come out of it the best: what :data:`EXPLORE`
        bounds (with ``learning``, in the stints of a learning arm that "keeps learning", which
        have a share of their own). A measurement that made its arm the best was no detour, and
        counting it spent the share on the winner: on collaboration, Random won a one-stint
        re-measurement on noise at 3 minutes, MAP-Elites' next re-measurement no longer fitted,
        and Random, judged from then on against its own pace, ran the last 2 minutes alone (0.93
        of MAP-Elites). Whether a stint's arm came out best: its score at the next stint's start,
        or now for the last one."""
        stints = _by_stint(self.history)
        now = {arm: self.score(arm) for arm in ARMS if self._batches(arm)}
        seconds = 0.0
        for number, stint in stints.items():
            arm = stint[0].arm
            if number == 0 or stint[0].reason.startswith(BEST):
                continue
            if stint[0].reason.startswith("keeps learning") != learning:
                continue
            after = stints[number + 1][0].rates if number + 1 in stints else now
            if after.get(arm, -math.inf) < max(after.values()):
                seconds += sum(b.seconds for b in stint)
        return seconds

    def _end_stint(self) -> None:
        """After a stint that measured a losing arm: if it still loses, it waits twice as long; an
        arm that comes out best waits the least when it loses again."""
        stint = [b for b in self.history if b.stint == self.stint]
        if not stint or stint[0].reason == "first measurement":
            return
        arm = stint[0].arm
        others = [self.score(other) for other in ARMS if other != arm and self._batches(other)]
        if others and self.score(arm) >= max(others):
            self.patience[arm] = PATIENCE
        elif stint[0].reason.startswith("re-measure"):
            self.patience[arm] = min(2 * self.patience[arm], MAX_PATIENCE)

    def _fits(self, search: SearchView, arm: str) -> bool:
        """Whether ``arm``'s next batch would end before the time limit (SAS's ask cannot be cut)."""
        if arm != "sas":
            return True
        last = self._batches(arm)
        return (last[-1].seconds if last else self._expected_seconds(arm)) <= search.seconds_left

    def _expected_seconds(self, arm: str) -> float:
        """What a stint of ``arm`` should take: a quantum, or one of its batches if longer (as long
        as its last one). A first one: one batch of its size at the recent seconds per evaluation
        (for SAS, of its largest size yet, and its surrogate's share of the time besides),
        :data:`WARMUP` of them for an arm that adapts."""
        if done := self._batches(arm):
            return max(self.quantum(), done[-1].seconds)
        if arm == "sas":
            batch = self.arms["sas"].largest * self._seconds_per_evaluation() / (1 - self.share)
        else:
            batch = self.arms[arm].batch_size * self._seconds_per_evaluation()
        return max(self.quantum(), (WARMUP if arm in ADAPTING else 1) * batch)

    def _pace(self, index: int, *, before: bool) -> float | None:
        """The search's QD-score gained per second over the last :data:`PACE` quanta of time
        before ``history[index]`` (all of it, early on), or over as long after ``history[index - 1]``
        (None until the search has gone on for that long)."""
        window, gain, seconds = PACE * self.quantum(), 0.0, 0.0
        batches = reversed(self.history[:index]) if before else iter(self.history[index:])
        for b in batches:
            if seconds >= window:
                break
            gain, seconds = gain + b.gain, seconds + b.seconds
        if not before and seconds < window:
            return None
        return gain / seconds if seconds > 0 else 0.0

    def _since(self, arm: str) -> float:
        """Seconds the other arms have had since ``arm``'s last batch."""
        last = self._batches(arm)[-1].batch
        return sum(b.seconds for b in self.history[last:])

    def _stale(self, arm: str) -> bool:
        """Whether the others have had :data:`PATIENCE` times ``arm``'s last stint since its last
        batch, as long as a losing arm waits to be measured again: where it stopped, the search
        has since moved on (a CMA-MAE that came back as the best after a minute away and went on
        from there scored under half the pace, on teleoperation). Not after a shorter pause: a
        restarted CMA-ES needs generations to adapt again, and restarting CMA-MAE after every
        second-long stint of another arm cost it its lead for 43 s of a 2-minute teleoperation run."""
        return self._since(arm) >= PATIENCE * self._last_stint_seconds(arm)

    def _last_stint_seconds(self, arm: str) -> float:
        last = self._batches(arm)[-1].stint
        return sum(b.seconds for b in self.history if b.stint == last)

    def _stints(self, arm: str) -> list[list[Batch]]:
        """``arm``'s stints, each its batches, in order."""
        return list(_by_stint(self._batches(arm)).values())

    def _seconds_per_evaluation(self) -> float:
        """The model-free arms' recent wall seconds per evaluation (proposing costs them next to
        nothing: this is what simulating one costs, with these workers)."""
        recent, seconds, evaluations = PACE * self.quantum(), 0.0, 0
        for b in reversed(self.history):
            if b.arm != "sas":
                seconds, evaluations = seconds + b.seconds, evaluations + b.evaluations
            if seconds >= recent:
                break
        return seconds / evaluations if evaluations else math.inf

    def _batches(self, arm: str) -> list[Batch]:
        return [b for b in self.history if b.arm == arm]

    # --- what it tells the user ---------------------------------------------------------------

    def summary(self) -> dict:
        """Per arm: stints, batches, evaluations, seconds and their share, QD-score gained, the
        recent rate and score."""
        total = self.spent or 1.0
        return {
            "arms": {
                arm: {
                    "stints": len({b.stint for b in done}),
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
        return [
            asdict(b) | {"pace": round(b.pace, 4), "rate": round(b.rate, 4), "relative": round(b.relative, 4)}
            for b in self.history
        ]


def _by_stint(batches: list[Batch]) -> dict[int, list[Batch]]:
    """``batches`` grouped by stint, in order."""
    stints: dict[int, list[Batch]] = {}
    for b in batches:
        stints.setdefault(b.stint, []).append(b)
    return stints


def _ratio(gain: float, expected: float) -> float:
    """Gain over expected gain; when the pace was nil, any gain counts as keeping pace."""
    if expected > 0:
        return gain / expected
    return 1.0 if gain > 0 else 0.0
