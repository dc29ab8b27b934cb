"""Quality-diversity search over a domain's scenarios, into a run directory.

``start`` begins a run, ``resume`` continues a killed one; both return the finished
:class:`Search`, whose run directory holds everything (see :mod:`hritest.rundir`). Each holds the
run's lock for the whole search, so one run directory has one writer.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from hritest.domain import compile_spec, load_domain
from hritest.errors import HritestError
from hritest.rundir import RunDirectory, RunDirectoryError, digest
from hritest.search.auto import sas_options
from hritest.search.executor import DomainRef, Evaluator, local_pool
from hritest.search.loop import ALGORITHMS, SURROGATE, Search, Snapshot
from hritest.search.proposers import SurrogateOptions
from hritest.spec import load_spec

__all__ = ["ALGORITHMS", "Backend", "Search", "Snapshot", "SurrogateOptions", "resume", "start"]


@dataclass(frozen=True, kw_only=True)
class Backend:
    """Where evaluations run: ``workers`` local processes, or a Dask cluster at ``cluster``."""

    workers: int = os.cpu_count() or 1
    cluster: str | None = None
    timeout: float = 300.0

    def evaluator(self, ref: DomainRef) -> Evaluator:
        if self.workers < 1:
            raise HritestError(f"--workers must be at least 1, got {self.workers}")
        if self.cluster is None:
            return Evaluator(
                ref=ref, make_executor=lambda: local_pool(self.workers), workers=self.workers, timeout=self.timeout
            )
        client = _dask_client(self.cluster)
        workers = max(1, sum(w.get("nthreads", 1) for w in client.scheduler_info()["workers"].values()))
        return Evaluator(
            ref=ref, make_executor=client.get_executor, workers=workers, timeout=self.timeout, on_close=client.close
        )


def _dask_client(address: str):  # noqa: ANN202 - distributed.Client
    try:
        from distributed import Client
    except ImportError:
        raise HritestError("--cluster needs Dask: pip install 'hritest[cluster]'") from None
    try:
        return Client(address, timeout=10)
    except (OSError, TimeoutError, ValueError) as exc:  # ValueError: not an address
        raise HritestError(
            f"cannot reach the Dask scheduler at {address} ({exc}); check the address and that "
            "'dask scheduler' is running there"
        ) from None


def start(
    *,
    spec_file: Path,
    out: Path | None,
    root: Path = Path("runs"),
    algorithm: str | None = None,
    budget: int | None = None,
    seed: int | None = None,
    time_limit: float | None = None,
    backend: Backend = Backend(),
    surrogate: SurrogateOptions | None = None,
    progress: Callable[[Snapshot], None] = lambda s: None,
) -> Search:
    """Runs a new search of the spec at ``spec_file``; arguments given override the spec's ``search``.

    ``time_limit`` (seconds, counted from this call) stops the search whatever its budget; given
    without ``budget``, it is the only limit (the spec's budget does not apply).
    """
    deadline = _deadline(time_limit)
    surrogate = surrogate or SurrogateOptions()
    spec = load_spec(spec_file)
    domain = compile_spec(spec)
    settings = spec.search
    algorithm = algorithm or settings.algorithm
    if algorithm not in ALGORITHMS:
        raise HritestError(f"unknown algorithm {algorithm!r}; choose one of {', '.join(ALGORITHMS)}")
    if budget is None and time_limit is None:
        budget = settings.budget
    seed = seed if seed is not None else settings.seed
    initial = settings.surrogate.initial_evaluations
    if algorithm in SURROGATE and budget is not None and budget <= initial:
        # It would spend the whole budget on the uniform initial sample: a Random search recorded
        # as SAS/DSAS, which a comparison of algorithms would take at its word.
        raise HritestError(
            f"{algorithm} with a budget of {budget} evaluations never uses its surrogate: the first "
            f"{initial} (search.surrogate.initial_evaluations) are uniform random samples. Give a budget "
            f"above {initial} (--budget or search.budget), lower search.surrogate.initial_evaluations, "
            "or use --algorithm random"
        )
    ref = DomainRef(spec=str(Path(spec_file).resolve()), base=str(Path(spec_file).resolve().parent))
    meta = {"algorithm": algorithm, "budget": budget, "time_limit": time_limit, "seed": seed, "spec_base": ref.base}
    # auto's SAS arm runs with a schedule of its own (auto.sas_options): record that one
    chosen = (sas_options(surrogate, settings.surrogate) if algorithm == "auto" else surrogate).applied_to(
        settings.surrogate
    )
    if algorithm in (*SURROGATE, "auto"):  # what decides a surrogate's cost and quality besides the budget
        meta |= chosen.model_dump(include={"inner_iterations", "training", "inner_stall", "selection", "screen"})
    if algorithm in SURROGATE:  # auto's SAS arm is never pipelined and has its time set by auto
        meta |= chosen.model_dump(include={"pipeline", "time_share"})
    evaluator = backend.evaluator(ref)  # before the folder exists: a bad backend leaves nothing behind
    try:
        run = RunDirectory.create(root=root, spec_file=spec_file, name=spec.name, folder=out, meta=meta)
        with run.lock():
            search = Search.new(
                domain=domain, run=run, algorithm=algorithm, budget=budget, seed=seed, options=surrogate
            )
            _run(search, evaluator, progress, deadline)
    finally:
        evaluator.close()
    return search


def _run(search: Search, evaluator: Evaluator, progress: Callable[[Snapshot], None], deadline: float | None) -> None:
    """Runs the search to its end, and says in ``run.json`` why it stopped."""
    search.run(evaluator, progress, deadline=deadline)
    write_log = getattr(search.state.proposer, "write_log", None)  # auto's: where the time went, and why
    search.run_dir.update_meta(
        stopped="budget" if search.done else "time limit", **({"auto": write_log(search.run_dir)} if write_log else {})
    )


def _deadline(time_limit: float | None) -> float | None:
    return None if time_limit is None else time.monotonic() + time_limit


def resume(
    *,
    run_path: Path,
    time_limit: float | None = None,
    backend: Backend = Backend(),
    progress: Callable[[Snapshot], None] = lambda s: None,
    trust: bool = False,
) -> Search:
    """Continues the run at ``run_path`` from its last checkpoint.

    It runs for ``time_limit`` seconds from this call, or, without one, for the run's own time
    limit again (``run.json``'s ``time_limit``; none: to the end of its budget).

    Every file the resume reads is checked first, and nothing in the run changes unless all agree.
    ``trust`` loads a checkpoint and plugin files that this user did not write (see
    :mod:`hritest.rundir`), for runs from someone the user trusts; the run becomes the user's
    (signed with their key), so that reports and replays of it need no further opt-in.

    Raises:
        RunDirectoryError: not a run directory; another search writing it; a spec changed since
            the run started; an unverified checkpoint or plugin file; files that disagree.
    """
    deadline = _deadline(time_limit)
    run = RunDirectory.open(run_path)
    missing = [k for k in ("spec_file", "spec_digest", "spec_base", "algorithm", "seed") if k not in run.meta]
    if missing:
        raise RunDirectoryError(
            f"{run.path / 'run.json'} lacks {', '.join(missing)}; it was not written by 'hritest search', "
            "and the run cannot be resumed"
        )
    with run.lock():
        run.check_spec()
        original = Path(run.meta["spec_file"])
        if original.is_file() and digest(original) != run.meta["spec_digest"]:
            raise RunDirectoryError(
                f"{original} changed since this run started; resuming would mix two different searches. "
                f"Start a new run, or restore the spec (the run's copy is {run.path / 'spec.yaml'})"
            )
        base = run.plugin_base(trust=trust)
        domain = load_domain(run.path / "spec.yaml", base=base)
        evaluator = backend.evaluator(DomainRef(spec=str(run.path / "spec.yaml"), base=run.meta["spec_base"]))
        try:
            search = Search.resume(domain=domain, run=run, trust=trust)
            if trust:
                run.adopt()
            if time_limit is not None:
                run.update_meta(time_limit=time_limit)
            limit = run.meta.get("time_limit")
            _run(search, evaluator, progress, deadline if time_limit is not None else _deadline(limit))
        finally:
            evaluator.close()
    return search
