"""The search's state as the checkpoint holds it, and the checks a resume makes before using it.

:class:`SearchState` is what ``checkpoint.pkl`` holds: the run's settings, the proposer and the
result archive (live pyribs / torch objects, changed in place by ask and tell), and the counters
the loop replaces after every batch. It is frozen so that a step builds the next state with
:func:`dataclasses.replace` and a checkpoint is always one consistent value; the proposer and the
archive inside it are not, and cannot be (pyribs mutates them).

A resume trusts nothing it reads: :func:`check_resumable` compares the checkpoint with
``run.json``, ``evaluations.jsonl`` and ``occupancy.f32`` before the run directory is touched,
and any disagreement is a :class:`RunDirectoryError` naming the file and what is wrong.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from hritest.records import EvaluationRecord
from hritest.rundir import RunDirectory, RunDirectoryError


@dataclass(frozen=True, kw_only=True)
class PendingBatch:
    """A batch asked and checkpointed but not yet told: evaluations ``first .. first + count - 1``."""

    batch: int
    solutions: np.ndarray
    first: int
    count: int


@dataclass(frozen=True, kw_only=True)
class ProgressRow:
    """One line of ``progress.csv``, written after each batch is told."""

    evaluations: int
    batch: int
    wall_time: float
    qd_score: float
    normalized_qd_score: float
    coverage: float
    best: float
    failures: int
    proposer: str = ""  # what proposed the batch: the algorithm, or what auto chose
    # Of wall_time, spent proposing it (SAS/DSAS: training, inner loop). Pipelined, the next batch is
    # asked while this one simulates: then the wait for that ask once this batch was done.
    propose_seconds: float = 0.0


@dataclass(frozen=True, kw_only=True)
class SearchState:
    """Everything a search needs to continue exactly where it stopped.

    ``evaluations`` counts the told evaluations; ``pending`` is the batch asked after them, if any;
    ``ahead``, the solutions of the batch after that, asked while ``pending`` simulated (a pipelined
    SAS / DSAS), to be simulated next.
    """

    algorithm: str
    budget: int | None  # None: no evaluation budget (a time limit stops the run)
    seed: int
    proposer: Any  # hritest.search.proposers.ModelFree | SurrogateAssisted
    result: Any  # ribs.archives.GridArchive: the raw objectives of successful evaluations
    evaluations: int = 0
    batch: int = 0
    pending: PendingBatch | None = None
    ahead: np.ndarray | None = None
    elapsed: float = 0.0
    progress: tuple[ProgressRow, ...] = ()

    @property
    def known(self) -> int:
        """Evaluations the checkpoint accounts for: the told ones and the pending batch's."""
        return self.evaluations + (self.pending.count if self.pending else 0)

    def progress_rows(self) -> list[dict[str, float]]:
        return [asdict(row) for row in self.progress]

    @classmethod
    def of(cls, loaded: object, *, path: Any) -> SearchState:
        """The state a checkpoint holds: a :class:`SearchState`, or the plain dict that run
        directories written before it hold (converted). ``path`` names the file in errors.

        Raises:
            RunDirectoryError: neither.
        """
        if isinstance(loaded, cls):
            return loaded
        if not isinstance(loaded, Mapping):
            raise RunDirectoryError(
                f"{path} holds a {type(loaded).__name__}, not a search state; the run cannot be resumed"
            )
        try:
            pending = loaded["pending"]
            return cls(
                **{f.name: loaded[f.name] for f in fields(cls) if f.name not in ("pending", "ahead", "progress")},
                pending=None if pending is None else PendingBatch(**pending),
                progress=tuple(ProgressRow(**row) for row in loaded["progress"]),
            )
        except (KeyError, TypeError) as exc:
            raise RunDirectoryError(
                f"{path} holds a search state this hritest cannot read ({type(exc).__name__}: {exc}); "
                "the run cannot be resumed. Start a new search"
            ) from None


def evaluation_seed(seed: int, index: int) -> int:
    """The seed of evaluation ``index``: independent of which worker runs it, or when."""
    return int(np.random.SeedSequence([seed, index]).generate_state(1)[0])


def load_state(run: RunDirectory, *, trust: bool = False) -> SearchState | None:
    """The run's checkpointed state (``None`` without a checkpoint), verified as written by this user
    unless ``trust`` (see :meth:`RunDirectory.load_checkpoint`)."""
    loaded = run.load_checkpoint(trust=trust)
    return None if loaded is None else SearchState.of(loaded, path=run.path / "checkpoint.pkl")


def check_resumable(
    state: SearchState, *, run: RunDirectory, records: Iterable[EvaluationRecord], dim: int, grid_shape: tuple[int, ...]
) -> int:
    """Checks that the files a resume reads agree; returns how many evaluation lines to keep.

    Kept are the evaluations the checkpoint knows of, which must lead ``evaluations.jsonl``:
    every told one, each once, with this run's seeds, then any of the pending batch that
    finished. Lines after them are evaluations of a batch the checkpoint never saw (a run packed
    or killed in between), which the resume drops. ``occupancy.f32`` needs a record for every line
    kept. ``records`` is read once, in order, and not kept (a long run's would fill the memory).

    Raises:
        RunDirectoryError: the first disagreement found, naming the file; nothing was changed.
    """
    checkpoint, lines = run.path / "checkpoint.pkl", run.path / "evaluations.jsonl"
    for name in ("algorithm", "seed"):
        if getattr(state, name) != run.meta.get(name):
            raise RunDirectoryError(
                f"{checkpoint} is of a run with {name} {getattr(state, name)!r}, but {run.path / 'run.json'} "
                f"says {run.meta.get(name)!r}: the two files come from different runs. Start a new search"
            )
    pending = state.pending
    if (
        pending is not None
        and (pending.first != state.evaluations or np.shape(pending.solutions)[1:] != (dim,) or pending.count < 0)
    ) or (state.ahead is not None and np.shape(state.ahead)[1:] != (dim,)):
        raise RunDirectoryError(
            f"{checkpoint}'s pending batch does not follow its {state.evaluations} told evaluations in this "
            f"spec's {dim}-dimensional space; the checkpoint is corrupt. Start a new search"
        )
    seen = np.zeros(state.known, bool)
    keep, twice, late, foreign, leading = 0, False, [], None, True
    for record in records:
        known = 0 <= record.index < state.known
        if leading and known:
            twice = twice or bool(seen[record.index])
            seen[record.index] = True
            keep += 1
            if foreign is None and (
                record.seed != evaluation_seed(state.seed, record.index) or len(record.theta) != dim
            ):
                foreign = record.index
        else:  # past the lines the checkpoint knows of
            leading = False
            if known:
                late.append(record.index)
    missing = np.flatnonzero(~seen[: state.evaluations]).tolist()
    if missing or late or twice:
        problem = (
            f"{_few(missing)} missing"
            if missing
            else "an evaluation is there twice"
            if twice
            else f"{_few(late)} after evaluations of a later batch"
        )
        raise RunDirectoryError(
            f"{lines} does not match {checkpoint}, which counts {state.evaluations} told evaluations: {problem}. "
            "The file was shortened, edited or written by two searches at once; the run cannot be resumed. "
            "Restore the file, or start a new search"
        )
    if foreign is not None:
        raise RunDirectoryError(
            f"{lines}: evaluation {foreign} is not one of this run's (its seed or theta's size differs "
            f"from what run seed {state.seed} and the spec give); the run cannot be resumed. Start a new search"
        )
    size = int(np.prod(grid_shape)) * np.dtype(np.float32).itemsize
    grids = run.path / "occupancy.f32"
    stored = grids.stat().st_size if grids.exists() else 0
    if stored < keep * size or (size == 0 and stored):
        raise RunDirectoryError(
            f"{grids} holds {stored} bytes, but the {keep} evaluations of {lines} need "
            f"{keep * size} ({keep} records of {size}): it was truncated or belongs to another task. "
            "The surrogate would learn from missing grids; restore the file, or start a new search"
        )
    return keep


def _few(indices: list[int]) -> str:
    """``evaluation 7 is`` or ``evaluations 1, 2, 3, 4, 5 and 6 more are``."""
    if len(indices) == 1:
        return f"evaluation {indices[0]} is"
    shown = ", ".join(map(str, indices[:5]))
    return f"evaluations {shown}" + (f" and {len(indices) - 5} more" if len(indices) > 5 else "") + " are"
