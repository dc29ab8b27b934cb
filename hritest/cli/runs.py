"""The commands of a search and what comes of it: search, report, replay, shrink and promote."""

from __future__ import annotations

import math
import os
import threading
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from hritest.cli.app import (
    ExitCode,
    JsonOption,
    command,
    domain_and_theta,
    duration,
    err,
    out,
    print_json,
)
from hritest.errors import HritestError
from hritest.records import MAX_SEED


@command
def search(
    spec: Annotated[
        Path | None, typer.Argument(help="the spec to search (omit with --resume)", show_default=False)
    ] = None,
    resume: Annotated[
        Path | None, typer.Option(help="continue the killed run in this run directory", rich_help_panel="Run")
    ] = None,
    algorithm: Annotated[
        str | None,
        typer.Option(
            help="random, map_elites, cma_mae, sas, dsas, or auto: whichever finds the most per second "
            "(default: the spec's)",
            rich_help_panel="Search",
        ),
    ] = None,
    budget: Annotated[
        int | None,
        typer.Option(
            min=1,
            help="real evaluations (default: the spec's, unless --time-limit is given alone)",
            rich_help_panel="Search",
        ),
    ] = None,
    time_limit: Annotated[
        float | None,
        typer.Option(
            parser=duration,
            metavar="DURATION",
            help="stop the search after this long (90, 90s, 15m, 2h; counted from the start, the workers' "
            "start-up included, and the report comes after it), or at --budget if that comes first; "
            "with --resume: run this much longer (default: the run's own limit again)",
            rich_help_panel="Search",
            show_default=False,
        ),
    ] = None,
    seed: Annotated[
        int | None, typer.Option(min=0, max=MAX_SEED, help="default: the spec's", rich_help_panel="Search")
    ] = None,
    out_dir: Annotated[
        Path | None, typer.Option("--out", help="run directory (default: runs/<spec>-<time>)", rich_help_panel="Run")
    ] = None,
    workers: Annotated[
        int, typer.Option(help="local worker processes (default: all cores)", rich_help_panel="Run")
    ] = os.cpu_count() or 1,
    cluster: Annotated[
        str | None, typer.Option(help="Dask scheduler address, e.g. tcp://host:8786", rich_help_panel="Run")
    ] = None,
    timeout: Annotated[
        float, typer.Option(help="seconds one scenario may take before it is stopped", rich_help_panel="Run")
    ] = 300.0,
    inner_iterations: Annotated[
        int | None,
        typer.Option(
            min=1,
            help="SAS/DSAS inner-loop iterations per outer iteration (default: the spec's)",
            rich_help_panel="Surrogate",
        ),
    ] = None,
    device: Annotated[
        str, typer.Option(help="where the surrogate runs: auto, cpu or cuda", rich_help_panel="Surrogate")
    ] = "auto",
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="no progress output")] = False,
    trust: Annotated[
        bool,
        typer.Option(
            help="with --resume: load a checkpoint and plugin files that you did not write (a run from "
            "someone you trust, or from an older hritest); the run is signed as yours from then on",
            rich_help_panel="Run",
        ),
    ] = False,
) -> None:
    """Search for diverse failures; writes a run directory.

    Exit 1 if failures were found, 3 if no evaluation completed. Ctrl-C or SIGTERM stops it with
    130 or 143, checkpointed: --resume continues.
    """
    from hritest import search as qd

    if (spec is None) == (resume is None):
        raise typer.BadParameter("give a SPEC to start a search, or --resume RUN to continue one (not both)")
    if resume is not None:
        given = {
            "--algorithm": algorithm,
            "--budget": budget,
            "--seed": seed,
            "--out": out_dir,
            "--inner-iterations": inner_iterations,
            "--device": None if device == "auto" else device,
        }
        if ignored := [name for name, value in given.items() if value is not None]:
            raise typer.BadParameter(
                f"{', '.join(ignored)} cannot change a run being resumed: it continues with the settings it "
                "started with (see its run.json). Leave them out, or start a new search",
                param_hint="--resume",
            )
    elif trust:
        raise typer.BadParameter("only a resumed run is trusted; use it with --resume RUN", param_hint="--trust")
    if workers < 1:
        raise typer.BadParameter(f"must be at least 1, got {workers}", param_hint="--workers")
    if not 0 < timeout < math.inf:  # 0, a negative number or NaN would disable the timeout silently
        raise typer.BadParameter(f"must be a number of seconds above 0, got {timeout}", param_hint="--timeout")
    if out_dir is not None and out_dir.exists() and not out_dir.is_dir():
        raise typer.BadParameter(f"{out_dir} is a file; give a folder for the run directory", param_hint="--out")
    if device not in ("auto", "cpu", "cuda"):
        raise typer.BadParameter(f"must be auto, cpu or cuda, not {device!r}", param_hint="--device")
    backend = qd.Backend(workers=workers, cluster=cluster, timeout=timeout)
    with Progress(quiet) as progress:
        if resume is not None:
            found = qd.resume(run_path=resume, time_limit=time_limit, backend=backend, progress=progress, trust=trust)
        else:
            found = qd.start(
                spec_file=spec,
                out=out_dir,
                algorithm=algorithm,
                budget=budget,
                time_limit=time_limit,
                seed=seed,
                backend=backend,
                progress=progress,
                surrogate=qd.SurrogateOptions(inner_iterations=inner_iterations, device=device),
            )
    _print_summary(found)
    from hritest.report import write_report

    if not quiet:
        err.print("writing the report (re-simulating the failures it records)...", highlight=False)
    report = write_report(found.run_dir.path)
    out.print(f"report: {report}", highlight=False)
    if found.failed == found.written:
        err.print(
            f"no evaluation completed: see the status and message of each in {found.run_dir.path / 'evaluations.jsonl'}"
            " (try one with 'hritest simulate')",
            markup=False,
            highlight=False,
        )
        raise typer.Exit(ExitCode.INCOMPLETE)
    if found.failures():
        raise typer.Exit(ExitCode.FINDING)


class Progress:
    """Search progress on stderr: a bar that fits the terminal on one; without one (a CI log), a
    plain line when the search starts, every ``PLAIN_SECONDS`` while it runs (whatever it is
    doing, a long surrogate training included) and when it ends; nothing with ``quiet``.

    Both say what the search is doing (its phase and, for ``auto``, which algorithm proposes),
    evaluations per second, and the time left: to the time limit, or to the end of the budget at
    the rate so far, whichever comes first. Without a budget, the bar measures time.
    """

    PLAIN_SECONDS = 5.0

    def __init__(self, quiet: bool) -> None:
        from rich.progress import BarColumn, Progress, TextColumn
        from rich.table import Column

        self.plain = not quiet and not err.is_terminal
        self.bar = (
            None
            if quiet or self.plain
            else Progress(
                # One line at any width: the bar and the numbers share what the counts leave.
                TextColumn("[bold]search", table_column=Column(no_wrap=True)),
                BarColumn(bar_width=None, table_column=Column(ratio=1, min_width=5)),
                TextColumn("{task.fields[count]}", table_column=Column(no_wrap=True)),
                TextColumn("{task.fields[stats]}", table_column=Column(ratio=3, no_wrap=True, overflow="ellipsis")),
                TextColumn("{task.fields[left]}", table_column=Column(no_wrap=True)),
                console=err,
                transient=True,
                expand=True,
            )
        )
        self.task = None
        self.snapshot = None
        self.first: tuple[float, int] | None = None  # (time, evaluations) of the first snapshot
        self.stop = threading.Event()
        self.ticker = threading.Thread(target=self._tick, daemon=True)

    def __enter__(self) -> Progress:
        if self.bar:
            self.bar.start()
        if self.plain:
            self.ticker.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.bar:
            self.bar.stop()
        if self.plain:
            self.stop.set()
            self.ticker.join()
            if self.snapshot is not None:
                self._print_line()

    def __call__(self, snapshot) -> None:  # noqa: ANN001 - hritest.search.Snapshot
        if self.first is None:
            self.first = (time.monotonic(), snapshot.evaluations)
            if self.plain:
                self.snapshot = snapshot
                self._print_line()
        self.snapshot = snapshot
        if self.bar is None:
            return
        if self.task is None:
            self.task = self.bar.add_task("search", total=1.0, count="", stats="", left="")
        self.bar.update(
            self.task,
            completed=self._done(snapshot),
            count=self._count(snapshot),
            stats=self._stats(snapshot),
            left=self._left(snapshot),
        )

    def _tick(self) -> None:
        while not self.stop.wait(self.PLAIN_SECONDS):
            if self.snapshot is not None:
                self._print_line()

    def _print_line(self) -> None:
        snapshot = self.snapshot
        err.print(
            f"search: {self._count(snapshot)} evaluations, {self._stats(snapshot)}, "
            f"{self._rate(snapshot):.3g} evaluations/s, {self._left(snapshot)}",
            markup=False,
            highlight=False,
        )

    def _rate(self, snapshot) -> float:  # noqa: ANN001 - hritest.search.Snapshot
        started, evaluations = self.first
        return (snapshot.evaluations - evaluations) / max(time.monotonic() - started, 1e-9)

    def _done(self, snapshot) -> float:  # noqa: ANN001 - hritest.search.Snapshot
        """The fraction done: of the budget, or without one, of the time limit."""
        if snapshot.budget is not None:
            return snapshot.evaluations / snapshot.budget
        started, _ = self.first
        return min(1.0, (time.monotonic() - started) / max(snapshot.deadline - started, 1e-9))

    def _left(self, snapshot) -> str:  # noqa: ANN001 - hritest.search.Snapshot
        left = math.inf if snapshot.deadline is None else max(0.0, snapshot.deadline - time.monotonic())
        rate = self._rate(snapshot)
        if snapshot.budget is not None and rate > 0:
            left = min(left, (snapshot.budget - snapshot.evaluations) / rate)
        return "time left -" if math.isinf(left) else f"{_clock(left)} left"

    @staticmethod
    def _count(snapshot) -> str:  # noqa: ANN001 - hritest.search.Snapshot
        return f"{snapshot.evaluations}" + ("" if snapshot.budget is None else f"/{snapshot.budget}")

    @staticmethod
    def _stats(snapshot) -> str:  # noqa: ANN001 - hritest.search.Snapshot
        s = snapshot.summary
        parts = [
            f"QD-score {s.qd_score:,.1f}, coverage {s.coverage:.1%}" if s else "QD-score -",
            f"failures {snapshot.failures}",
            f"did not complete {snapshot.failed}",
            f"{snapshot.phase} ({snapshot.proposer})" if snapshot.proposer else snapshot.phase,
        ]
        return ", ".join(parts)


def _clock(seconds: float) -> str:
    """``1:02:03``, ``4:05`` or ``0:07``."""
    minutes, secs = divmod(int(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


def _print_summary(found) -> None:  # noqa: ANN001 - hritest.search.Search
    from hritest.search.archives import Summary

    state = found.state
    summary = Summary.of(state.result, found.domain.spec.objective.range)
    statuses = found.statuses
    table = Table(
        title=f"{found.domain.spec.name}: {state.algorithm}, seed {state.seed}",
        title_justify="left",
        show_header=False,
    )
    rows = [
        ("run directory", str(found.run_dir.path)),
        ("evaluations", f"{state.evaluations} ({', '.join(f'{n} {k}' for k, n in sorted(statuses.items()))})"),
        ("wall time", f"{state.elapsed:.1f} s searching" + (", stopped at its time limit" if not found.done else "")),
        ("QD-score", f"{summary.qd_score:,.2f} (normalised {summary.normalized_qd_score:.4f})"),
        ("coverage", f"{summary.coverage:.2%} of {state.result.cells} cells"),
        ("best objective", f"{summary.best:.4g}"),
        ("failures", f"{len(found.failures())} elites meet '{found.domain.spec.failure}'"),
    ]
    for name, value in rows:
        table.add_row(name, value)
    out.print(table)


@command
def report(
    runs: Annotated[list[Path], typer.Argument(help="a run directory, or several to compare", show_default=False)],
    out_dir: Annotated[
        Path | None,
        typer.Option(
            "--out",
            help="report folder (default: RUN/report, or report-compare/ when comparing runs)",
            show_default=False,
        ),
    ] = None,
    recordings: Annotated[
        int, typer.Option(min=0, help="record the N worst failures, plus the most different ones, for Rerun (0: none)")
    ] = 10,
    trust: Annotated[
        bool,
        typer.Option(
            help="load a checkpoint and plugin files that you did not write (a run from someone you trust, or "
            "from an older hritest); the run is not signed as yours"
        ),
    ] = False,
) -> None:
    """Write a run's failure report (report/index.html and summary.md) and its failures' Rerun recordings.

    With several runs, write one page that compares them (no recordings).
    """
    from hritest.report import compare_runs, write_report

    if len(runs) == 1:
        page = write_report(runs[0], recordings=recordings, out=out_dir, trust=trust)
        folder = runs[0] / "recordings"
        if folder.is_dir() and recordings:
            out.print(f"recordings: {folder}", highlight=False)
    else:
        page = compare_runs(runs, out_dir if out_dir is not None else Path("report-compare"), trust=trust)
    out.print(f"report: {page}", highlight=False)


@command
def replay(
    target: Annotated[
        Path,
        typer.Argument(
            help="a run directory (with --failure), a corpus entry file, or a spec (with --theta)", show_default=False
        ),
    ],
    failure: Annotated[
        int | None,
        typer.Option(help="the failure's id in the run (see its report or failures.yaml)", show_default=False),
    ] = None,
    theta: Annotated[str | None, typer.Option(help="comma-separated theta, with a SPEC", show_default=False)] = None,
    seed: Annotated[int, typer.Option(min=0, max=MAX_SEED, help="the evaluation seed, with a SPEC")] = 0,
    out_path: Annotated[
        Path | None,
        typer.Option(
            "--out",
            help="where to write the recording (default: RUN/recordings/ID.rrd, or recordings/SPEC-DIGEST.rrd)",
            show_default=False,
        ),
    ] = None,
    open_: Annotated[bool, typer.Option("--open", help="open the recording in the Rerun viewer")] = False,
    tolerance: Annotated[float, typer.Option(min=0.0, help="absolute tolerance on the objective and measures")] = 1e-6,
    trust: Annotated[
        bool,
        typer.Option(
            help="with a run directory: load plugin files that you did not write (a run from someone you "
            "trust, or from an older hritest); the run is not signed as yours"
        ),
    ] = False,
) -> None:
    """Re-simulate a failure (or any scenario), check it reproduces, and write its Rerun recording.

    Exit 0 when the outcome matches the stored one (for a SPEC: a second simulation), 1 when not,
    3 when the scenario could not be evaluated.
    """
    from hritest import corpus as hc
    from hritest import recording
    from hritest import replay as rp
    from hritest.errors import HritestError as Bad
    from hritest.rundir import RunDirectory, digest

    if not target.exists():
        raise Bad(f"{target} does not exist; give a run directory (with --failure) or a spec (with --theta)")
    if trust and not target.is_dir():
        raise typer.BadParameter(
            "only a run directory is trusted; use it with a RUN and --failure ID", param_hint="--trust"
        )
    if target.is_dir():
        if failure is None or theta is not None:
            raise typer.BadParameter("with a run directory give --failure ID (and no --theta)", param_hint="--failure")
        run = RunDirectory.open(target)
        record = rp.stored_failure(run, failure)  # bad input fails before anything is written
        path = recording.check_writable(out_path or run.path / "recordings" / f"{failure}.rrd")
        domain = rp.run_domain(run, trust=trust)
        result = rp.replay_record(domain, record, spec_digest=run.meta["spec_digest"], tolerance=tolerance)
        title = f"{result.domain.spec.name}: failure {failure} ({run.path.resolve().name})"
    elif hc.is_entry(target):
        if failure is not None or theta is not None:
            raise typer.BadParameter(
                "a corpus entry replays its own theta and seed: give neither", param_hint="--theta"
            )
        path = recording.check_writable(out_path or Path("recordings") / f"{target.stem}.rrd")
        result = hc.replay_entry(target, tolerance=tolerance)
        title = f"{result.domain.spec.name}: corpus entry {target.stem}"
    else:
        if theta is None or failure is not None:
            raise typer.BadParameter("with a spec give --theta v1,v2,... (and no --failure)", param_hint="--theta")
        domain, values = domain_and_theta(target, theta)
        if out_path is not None:
            recording.check_writable(out_path)
        result = rp.replay_theta(domain, values, seed=seed, spec_digest=digest(target), tolerance=tolerance)
        path = recording.check_writable(out_path or Path("recordings") / f"{domain.spec.name}-{result.digest[:12]}.rrd")
        title = f"{domain.spec.name}: seed {seed}"
    recording.write_recording(
        path,
        domain=result.domain,
        evaluation=result.evaluation,
        rollout=result.rollout,
        recording_id=result.digest,
        title=title,
    )
    _print_replay(result)
    out.print(f"recording: {path}", highlight=False)
    if open_:
        recording.open_viewer(path)
    if not result.evaluation.ok:
        raise typer.Exit(ExitCode.INCOMPLETE)
    if not result.matches:
        raise typer.Exit(ExitCode.FINDING)


@command
def shrink(
    run: Annotated[Path, typer.Argument(help="the run directory", show_default=False)],
    failure: Annotated[
        int, typer.Option(help="the failure's id (see the report or failures.yaml)", show_default=False)
    ],
    budget: Annotated[int, typer.Option(min=1, help="the most simulations to spend")] = 100,
    clause: Annotated[
        str | None,
        typer.Option(help="the failure clause to keep (default: the first that holds)", show_default=False),
    ] = None,
    json: JsonOption = False,
) -> None:
    """Shrink a failure: move its parameters toward nominal while the same failure clause holds.

    Prints which parameters still matter, and stores the shrunk scenario in RUN/shrunk/ID.json.
    """
    from hritest.shrink import shrink_failure

    result, path = shrink_failure(run, failure, clause=clause, budget=budget)
    if json:
        print_json({"failure": failure, **result.to_json()})
        return
    table = Table(title=f"failure {failure}, shrunk: '{result.clause}' still holds", title_justify="left")
    for column in ("parameter", "original", "shrunk", "nominal", ""):
        table.add_column(column, justify="left" if column in ("parameter", "") else "right")
    for name, row in result.to_json()["parameters"].items():
        values = [", ".join(f"{v:.4g}" for v in row[k]) for k in ("original", "shrunk", "nominal")]
        table.add_row(name, *values, "[bold]still matters[/bold]" if row["matters"] else "nominal")
    out.print(table)
    out.print(
        f"{len(result.off_nominal(result.original))} -> {len(result.off_nominal(result.theta))} parameters away "
        f"from nominal, in {result.evaluations} simulations; objective {result.evaluation.objective:.4g}",
        highlight=False,
    )
    out.print(f"saved: {path}", highlight=False)


def _print_replay(result) -> None:  # noqa: ANN001 - hritest.replay.Replay
    table = Table(title=f"replay against {result.against}", title_justify="left")
    for column in ("compared", result.reference, "replayed", ""):
        table.add_column(column, justify="right" if column in (result.reference, "replayed") else "left")

    def show(value: object) -> str:
        return f"{value:.10g}" if isinstance(value, float) else str(value)

    for check in result.checks:
        verdict = "[green]match[/green]" if check.ok else "[red]DIFFERS[/red]"
        table.add_row(check.name, show(check.stored), show(check.replayed), verdict)
    out.print(table)
    out.print(
        f"compared: status and failure verdict exactly; objective and measures within {result.tolerance:g} absolute",
        highlight=False,
    )
    out.print(result.why, markup=False, highlight=False)
    verdict = "[green]replay matches[/green]" if result.matches else "[red]replay does NOT match[/red]"
    out.print(f"{verdict} (scenario digest {result.digest[:16]})")


@command
def promote(
    run: Annotated[
        Path | None, typer.Argument(help="a run directory whose failures to keep", show_default=False)
    ] = None,
    top: Annotated[
        int | None, typer.Option(min=1, help="only the N worst failures (default: all)", show_default=False)
    ] = None,
    to: Annotated[
        Path | None,
        typer.Option(
            help="the corpus folder (default: \\[tool.hritest] corpus in the nearest "
            "pyproject.toml, else tests/hri_failures)",
            show_default=False,
        ),
    ] = None,
    shrink: Annotated[
        bool, typer.Option("--shrink", help="keep each failure's simplest version (hritest shrink) instead")
    ] = False,
    mark_fixed: Annotated[
        list[str] | None,
        typer.Option(
            "--mark-fixed",
            metavar="ID",
            help="set status: fixed on this corpus entry (its id, spec/id or file); repeat for several",
            show_default=False,
        ),
    ] = None,
) -> None:
    """Keep a run's failures in the failure corpus that pytest replays; mark corpus entries fixed.

    One YAML file per failure, CORPUS/SPEC/ID.yaml, status open (xfail under pytest) or fixed (must not fail again).
    """
    from hritest import corpus as hc
    from hritest.promote import promote as promote_run

    if run is None and not mark_fixed:
        raise typer.BadParameter("give a RUN directory to promote from, or --mark-fixed ID (or both)")
    folder = to if to is not None else hc.default_corpus(Path.cwd())
    if run is not None:
        if mark_fixed and not run.is_dir():
            raise HritestError(
                f"{run} is not a run directory; to mark several entries fixed repeat the "
                "option: --mark-fixed ID --mark-fixed ID"
            )
        promoted = promote_run(run, corpus=folder, top=top, shrink=shrink)
        for p in promoted:
            verb = "[green]added[/green]  " if p.added else "upgraded " if p.upgraded else "unchanged"
            out.print(f"{verb} {p.path}  (evaluation {p.evaluation}, objective {p.objective:.6g})", highlight=False)
        added = sum(p.added for p in promoted)
        out.print(
            f"{added} added, {len(promoted) - added} already in the corpus {folder}"
            + ("" if promoted else f" ({run} has no failures)"),
            highlight=False,
        )
    if mark_fixed:
        for path, before in hc.mark_fixed(folder, [i for ids in mark_fixed for i in ids.split(",") if i]):
            note = "was already fixed" if before == "fixed" else "open -> fixed"
            out.print(f"fixed {path}  ({note})", highlight=False)
