"""What proposes the next batch of scenarios to simulate: a pyribs scheduler, or SAS / DSAS.

A proposer has ``ask(search) -> solutions`` and ``tell(search, records, solutions)``; the search
loop evaluates what it asks and hands back the records in ask order. A proposer sees the search
only through :class:`SearchView`, so the loop depends on proposers and never the reverse. Both kinds are pickled
into the checkpoint whole, so a resumed run continues with the exact same state.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from hritest.domain import Domain
from hritest.records import EvaluationRecord
from hritest.rundir import RunDirectory
from hritest.search import archives, inner, screening
from hritest.spec.models import SurrogateSettings


class SearchView(Protocol):
    """What a proposer reads of the search that drives it."""

    domain: Domain
    run_dir: RunDirectory

    @property
    def evaluated(self) -> int:
        """Evaluations told so far."""
        ...

    @property
    def qd_score(self) -> float:
        """The result archive's QD-score, the batch just simulated included (when telling)."""
        ...

    @property
    def seconds_left(self) -> float:
        """Until the run's time limit (infinite without one)."""
        ...

    @property
    def seconds_per_evaluation(self) -> float | None:
        """What the last batch told took besides its proposing (simulating it, storing what came
        back) over its evaluations (None before the first)."""
        ...

    def dataset(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Training data of every successful evaluation: raw theta, grids, targets."""
        ...

    def elite_objectives(self, measures: np.ndarray) -> np.ndarray:
        """The result archive's objective in the cells of ``measures`` (the spec's measures), the
        objective range's low end where a cell is empty."""
        ...

    def gains(self, records: list[EvaluationRecord]) -> np.ndarray:
        """What each of ``records``, of the batch being told, added to the result archive's
        QD-score (0 where it added nothing or did not complete)."""
        ...

    def phase(self, name: str) -> None:
        """Shows what the proposer is doing (``training``, ``inner loop``) in the progress display."""
        ...


class ModelFree:
    """Random, MAP-Elites or CMA-MAE: the scheduler proposes, every proposal is simulated."""

    def __init__(self, scheduler) -> None:  # noqa: ANN001 - ribs Scheduler
        self.scheduler = scheduler

    @property
    def batch_size(self) -> int:
        """Solutions per ask: every emitter's batch."""
        return sum(emitter.batch_size for emitter in self.scheduler.emitters)

    def ask(self, search: SearchView) -> np.ndarray:
        return self.scheduler.ask()

    def tell(self, search: SearchView, records: list[EvaluationRecord], solutions: np.ndarray) -> None:
        """Tells full batches (a budget-truncated last batch ends the run anyway)."""
        if len(records) == len(solutions):
            self.scheduler.tell(*archive_inputs(search.domain, records))

    def observe(self, search: SearchView, records: list[EvaluationRecord], solutions: np.ndarray) -> None:
        """Adds evaluations that another proposer asked for to the archive the emitters climb, so
        that their improvement ranking measures against everything simulated (``auto``)."""
        objective, measures = archive_inputs(search.domain, records)
        self.scheduler.archive.add(np.asarray(solutions)[: len(records)], objective, measures)


def archive_inputs(domain: Domain, records: list[EvaluationRecord]) -> tuple[np.ndarray, np.ndarray]:
    """The search archive's objective and measures (the spec's, then the region axes) of ``records``.

    An evaluation that did not complete scores below any threshold, at the measures' low corner:
    ranked last, never an elite.
    """
    lo, hi = domain.spec.objective.range
    bad = lo - (hi - lo)
    ok = [r.ok and math.isfinite(r.search_objective) for r in records]
    objective = np.array([max(r.search_objective, bad) if good else bad for r, good in zip(records, ok)])
    measures = np.array(
        [r.measures if good else [m.range[0] for m in domain.measures] for r, good in zip(records, ok)],
        dtype=float,
    ).reshape(len(records), -1)
    regions = archives.region_measures(domain, [r.regions for r in records])
    return objective, np.hstack([measures, regions])


@dataclass(frozen=True, kw_only=True)
class SurrogateOptions:
    """Overrides of the spec's surrogate settings from the command line."""

    inner_iterations: int | None = None
    device: str = "auto"
    training: str | None = None
    inner_stall: int | None = None
    pipeline: bool | None = None
    time_share: float | None = None
    selection: str | None = None
    screen: bool | None = None

    # of the spec
    SETTINGS = ("inner_iterations", "training", "inner_stall", "pipeline", "time_share", "selection", "screen")

    def applied_to(self, settings: SurrogateSettings) -> SurrogateSettings:
        """The spec's ``search.surrogate`` with those of these options that were given (not None)."""
        given = {name: value for name in self.SETTINGS if (value := getattr(self, name)) is not None}
        return settings.model_copy(update=given)


class SurrogateAssisted:
    """SAS (CMA-MAE inner loop) or DSAS (CMA-MAEGA inner loop), the paper's Algorithm 1.

    The first ``initial_evaluations`` proposals are uniform in the bounds. After that, each ask
    is one outer iteration: train the surrogate on the evaluations so far (all of them each time,
    as the paper, or the new ones and as many replayed: ``training``), search it from scratch, and
    propose one surrogate elite per block of the selection grid (``selection``: the one predicted to
    add the most to the result archive, or, as the paper, any one), of which, with ``screen``, those
    whose predicted objective paid for its simulation in the last rounds (:mod:`screening`). Each
    proposal's prediction is kept, so that once simulated it measures the surrogate's accuracy
    on data it was not trained on (the paper's held-out evaluation).

    With ``pipeline``, the search loop asks for the next batch while the current one simulates
    (see :meth:`can_ask_ahead`): an outer iteration then trains on every evaluation but the
    batch in flight.
    """

    def __init__(self, domain: Domain, *, gradients: bool, seed: int, options: SurrogateOptions) -> None:
        from hritest.surrogate.model import Surrogate, pick_device

        settings = options.applied_to(domain.spec.search.surrogate)
        self.gradients, self.seed = gradients, seed
        self.iterations = settings.inner_iterations
        self.initial = settings.initial_evaluations
        self.rng = np.random.default_rng(seed)
        self.surrogate = Surrogate(
            bounds=(domain.space.lower, domain.space.upper),
            channels=len(domain.grids),
            outputs=1 + len(domain.measures),
            epochs=settings.epochs,
            batch_size=settings.batch_size,
            learning_rate=settings.learning_rate,
            device=pick_device(options.device),
            seed=seed,
        )
        self.training, self.stall, self.pipeline = settings.training, settings.inner_stall, settings.pipeline
        self.time_share, self.selection = settings.time_share, settings.selection
        self.screen = settings.screen and not settings.pipeline  # a pipelined round's work costs no wall time
        # Per batch told (the last screening.ROUNDS), the simulated proposals' predicted objective, the
        # QD-score each added and its seconds: what screening judges the next proposals by.
        self.outcomes: list[np.ndarray] = []
        self.trained = 0  # samples the surrogate had seen at its last fit
        self.largest = self.initial  # the largest batch proposed so far: what the time share is of
        self.outer = 0
        # Per batch asked and not yet told, oldest first: its outer iteration, proposals and their
        # predictions. Two are pending while a pipelined search asks ahead.
        self.predictions: list[tuple[int, np.ndarray, np.ndarray]] = []
        self.held_out: list[tuple[int, list[float], list[float]]] = []  # (outer iteration, predicted, true)
        self.fits: list[dict] = []

    def ask(self, search: SearchView, *, per_evaluation: float | None = None) -> np.ndarray:
        """One outer iteration's proposals. Its training and inner loop end by the time that
        ``time_share`` allows for simulating a batch at ``per_evaluation`` seconds a scenario (by
        default, as the last batch took; ``auto``, whose arms take turns, says what its model-free
        arms' took) or by the run's time limit, whichever comes first; training gets about half."""
        space = search.domain.space
        done = search.evaluated
        if done < self.initial:
            return self.rng.uniform(space.lower, space.upper, size=(self.initial - done, space.dim))
        started = time.monotonic()
        per_evaluation = search.seconds_per_evaluation if per_evaluation is None else per_evaluation
        seconds = self._seconds(per_evaluation)
        # Training and inner loop end by the run's time limit too: whatever they found is proposed.
        budget = min(math.inf if seconds is None else seconds, search.seconds_left)
        end = None if math.isinf(budget) else started + budget
        search.phase("training")
        theta, grids, targets = search.dataset()
        fit = self.surrogate.fit(
            theta,
            grids,
            targets,
            rows=self._rows(len(theta)),
            deadline=None if end is None else started + budget / 2,
        )
        self.trained = len(theta)
        self.outer += 1
        search.phase("inner loop")
        trained = time.monotonic()
        objective = inner.SurrogateObjective(search.domain, self.surrogate)
        archive = inner.exploit(
            search.domain,
            objective,
            gradients=self.gradients,
            iterations=self.iterations,
            stall=self.stall,
            seed=int(self.rng.integers(2**31)),
            deadline=end,
        )
        searched = time.monotonic()
        proposals = inner.downsample(
            search.domain,
            archive,
            rng=self.rng,
            incumbents=search.elite_objectives if self.selection == "gain" else None,
        )
        if len(proposals) == 0:  # an empty surrogate archive: explore instead of stalling
            proposals = self.rng.uniform(space.lower, space.upper, size=(8, space.dim))
        predictions = self.surrogate.predict(proposals)
        chosen = len(proposals)
        if self.screen:
            keep = self._worth(predictions[:, 0], overhead=searched - started, per_evaluation=per_evaluation)
            proposals, predictions = proposals[keep], predictions[keep]
        self.fits.append(
            {
                "outer_iteration": self.outer,
                "samples": fit.samples,
                "occupancy_loss": fit.occupancy_loss,
                "predictor_loss": fit.predictor_loss,
                "seconds_allowed": None if end is None else round(budget, 3),
                "training_seconds": round(trained - started, 3),
                "inner_iterations": objective.calls,
                "inner_loop_seconds": round(searched - trained, 3),
                "proposed": len(proposals),
                "screened_out": chosen - len(proposals),
            }
        )
        self.predictions.append((self.outer, proposals, predictions))
        self.largest = max(self.largest, len(proposals))
        return proposals

    def _worth(self, predicted: np.ndarray, *, overhead: float, per_evaluation: float | None) -> np.ndarray:
        """Which proposals of ``predicted`` (normalised) objective to simulate (:mod:`screening`).
        The round's ``overhead`` seconds of surrogate work are wall seconds, the outcomes' of
        single simulations: the workers' parallelism converts them, taken as the mean seconds of
        a simulation in SAS's last batch over the wall seconds a scenario took (``per_evaluation``:
        SAS's last batch's, or, under auto, the model-free arms' recent ones, whose shorter
        scenarios overstate the parallelism and so the overhead: an error toward simulating).
        Always at least one proposal, the highest predicted."""
        outcomes = np.concatenate(self.outcomes) if self.outcomes else np.zeros((0, 3))
        if per_evaluation is None or per_evaluation <= 0 or not len(outcomes):
            return np.ones(len(predicted), bool)
        parallel = max(float(np.mean(self.outcomes[-1][:, 2])) / per_evaluation, 1.0)
        keep = screening.worth_simulating(predicted, outcomes=outcomes, overhead=overhead * parallel)
        keep[np.argmax(predicted)] = True
        return keep

    def _seconds(self, per_evaluation: float | None) -> float | None:
        """What an outer iteration's surrogate work may take to keep to ``time_share`` of the run:
        the share of it over the rest, times what simulating a batch takes (on a domain whose
        scenarios take milliseconds, a fraction of a second; None: no cut). A batch as large as
        the largest it proposed, not its last: a short inner loop fills few cells and proposes few
        scenarios, and sized by those, the next would be shorter still (on teleoperation, batches
        of one scenario and one inner iteration each, from the second round on)."""
        if self.time_share >= 1 or per_evaluation is None:
            return None
        return per_evaluation * self.largest * self.time_share / (1 - self.time_share)

    def can_ask_ahead(self, search: SearchView) -> bool:
        """Whether the loop may ask for the next batch before the one simulating is told: with
        ``pipeline``, once the uniform initial batch is told (the surrogate needs data)."""
        return self.pipeline and search.evaluated >= self.initial

    def _rows(self, samples: int) -> np.ndarray | None:
        """What this round trains on: everything (the paper), or, incrementally, the samples new
        since the last round plus as many old ones drawn at random (at least a batch), so that
        the networks learn the new data without forgetting the old and a round costs the same
        however long the run.

        At most as many new samples as the largest batch it proposed, drawn at random; the rest
        count as old, for later rounds to replay. Only others add more between two rounds (auto's
        other arms, thousands of scenarios in a stint): trained on all of them in the same
        seconds, the networks saw each a fraction of an epoch, and SAS's proposals in auto were
        chosen by a surrogate whose predictor's loss was over ten times SAS alone's (collaboration)."""
        if self.training == "paper" or (self.trained == 0 and samples <= self.largest):
            return None
        rng = np.random.default_rng([self.seed, self.outer])
        new = np.arange(self.trained, samples)
        if len(new) > self.largest:
            new = np.sort(rng.choice(new, size=self.largest, replace=False))
        replay = min(self.trained, max(len(new), self.surrogate.batch_size))
        old = rng.choice(self.trained, size=replay, replace=False)
        return np.concatenate([np.sort(old), new])

    def __setstate__(self, state: dict) -> None:
        # Checkpoints written before the incremental schedule existed trained the paper's way, and
        # those from before time_share never cut its work, those from before selection chose at
        # random; those from before pipelining kept one batch's predictions without its proposals
        # (dropped: their held-out errors go unmeasured); those from before screening simulated every
        # proposal.
        state.pop("pending_predictions", None)
        before = {
            "training": "paper",
            "stall": None,
            "trained": 0,
            "pipeline": False,
            "predictions": [],
            "time_share": 1.0,
            "selection": "random",
            "largest": state["initial"],
            "screen": False,
            "outcomes": [],
        }
        self.__dict__.update({**before, **state})

    def tell(self, search: SearchView, records: list[EvaluationRecord], solutions: np.ndarray) -> None:
        asked = [i for i, (_, proposals, _) in enumerate(self.predictions) if np.array_equal(proposals, solutions)]
        if not asked:  # a uniform batch
            return
        outer, _, predictions = self.predictions[asked[0]]
        del self.predictions[: asked[0] + 1]
        outcome = np.column_stack([predictions[: len(records), 0], search.gains(records), [r.seconds for r in records]])
        self.outcomes = [*self.outcomes[1 - screening.ROUNDS :], outcome]
        lo, hi = search.domain.spec.objective.range
        for record, predicted in zip(records, predictions):
            if record.ok:
                true = [record.search_objective / (hi - lo), *record.measures]
                self.held_out.append((outer, predicted.tolist(), true))
        search.run_dir.write_text("surrogate.json", json.dumps(self.accuracy(search.domain), indent=2))

    def accuracy(self, domain: Domain) -> dict:
        """Held-out errors the paper's way (MAE per output, right-cell fraction, cell distance),
        over every proposal so far and per outer iteration, with each training round's losses."""
        if not self.held_out:
            return {"held_out": 0, "fits": self.fits}
        outers = sorted({outer for outer, _, _ in self.held_out})
        per_outer = [
            {"outer_iteration": outer, **_errors(domain, [h for h in self.held_out if h[0] == outer])}
            for outer in outers
        ]
        return {**_errors(domain, self.held_out), "per_outer_iteration": per_outer, "fits": self.fits}


def _errors(domain: Domain, held_out: list[tuple[int, list[float], list[float]]]) -> dict:
    predicted = np.array([p for _, p, _ in held_out])
    true = np.array([t for _, _, t in held_out])
    lo, hi = domain.spec.objective.range
    scale = np.array([hi - lo] + [1.0] * len(domain.measures))
    errors = np.abs(predicted - true) * scale
    archive = archives.result_archive(domain, seed=0)
    predicted_index, true_index = archive.index_of(predicted[:, 1:]), archive.index_of(true[:, 1:])
    if domain.spec.archive.type == "cvt":  # the distance between the cells' centroids, in ranges
        width = np.array([hi - lo for lo, hi in domain.archive_ranges])
        apart = np.linalg.norm((archive.centroids[predicted_index] - archive.centroids[true_index]) / width, axis=1)
    else:  # cells apart, summed over the measures
        apart = np.abs(
            np.array(np.unravel_index(predicted_index, archive.dims))
            - np.array(np.unravel_index(true_index, archive.dims))
        ).sum(axis=0)
    return {
        "held_out": len(true),
        "objective_mae": float(errors[:, 0].mean()),
        "measure_mae": {m.name: float(errors[:, i + 1].mean()) for i, m in enumerate(domain.measures)},
        "right_cell_fraction": float((predicted_index == true_index).mean()),
        "mean_cell_distance": float(apart.mean()),
    }
