"""The ``hritest`` command line; its exit codes are :class:`ExitCode`, the same for every command."""

from __future__ import annotations

import contextlib
import functools
import math
import os
import signal
import sys
import tempfile
import threading
import time
import traceback
from enum import IntEnum
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

import hritest
from hritest.errors import HritestError
from hritest.interrupt import Interrupted, stop_on_signals

app = typer.Typer(
    no_args_is_help=True,
    add_completion=False,
    help="Find where a robot policy fails with people, and keep those failures as tests.",
    pretty_exceptions_enable=False,
)
out = Console(soft_wrap=True)
err = Console(stderr=True, soft_wrap=True)


class ExitCode(IntEnum):
    """What hritest's exit status means, for every command (README, "Exit codes")."""

    OK = 0
    FINDING = 1  # failures found, a replay that does not reproduce, a scenario that cannot be repaired
    INPUT = 2  # bad input: a spec, plugin, argument, run directory or corpus file; the message says what
    INCOMPLETE = 3  # an evaluation could not complete (plugin error, NaN, timeout, crash); a search: none did
    BUG = 4  # hritest itself failed; the traceback is in a file the message names
    INTERRUPTED = 128 + signal.SIGINT  # Ctrl-C; a search checkpointed and says how to resume
    TERMINATED = 128 + signal.SIGTERM  # SIGTERM; the same


SpecArg = Annotated[Path, typer.Argument(help="a hritest spec (YAML)", show_default=False)]


def command(fn):  # noqa: ANN001, ANN201 - a typer command
    """Registers ``fn`` as a command, whose exit status says what happened (:class:`ExitCode`).

    hritest's own errors (bad input) become their message and exit 2; SIGINT and SIGTERM stop it
    with 130 and 143 (a search first saying how to resume); any other exception is a bug in
    hritest: one line, and its traceback in a file, exit 4. No traceback reaches the terminal.
    """

    @functools.wraps(fn)
    def run(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        try:
            with stop_on_signals():
                return fn(*args, **kwargs)
        except HritestError as exc:
            err.print(str(exc), markup=False, highlight=False)
            raise typer.Exit(ExitCode.INPUT) from None
        except (Interrupted, KeyboardInterrupt) as exc:
            raise typer.Exit(_interrupted(exc)) from None
        except (typer.Exit, typer.Abort, typer.TyperException):
            raise
        except Exception as exc:
            _bug(exc)
            raise typer.Exit(ExitCode.BUG) from None

    return app.command()(run)


def _interrupted(exc: BaseException) -> ExitCode:
    signum = exc.signum if isinstance(exc, Interrupted) else signal.SIGINT
    run = exc.run if isinstance(exc, Interrupted) else None
    name = "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name
    if run is None:
        err.print(f"stopped by {name}", highlight=False)
    else:
        err.print(
            f"stopped by {name}; the run is checkpointed in {run}. Continue it with:\n  hritest search --resume {run}",
            markup=False,
            highlight=False,
        )
    return ExitCode.INTERRUPTED if signum == signal.SIGINT else ExitCode.TERMINATED


def _bug(exc: Exception) -> None:
    """Says that hritest failed, and where its traceback is: the run directory's error.log
    when a search wrote one, else a new file in the temporary folder."""
    path = getattr(exc, "traceback_file", None)
    if path is None:
        with tempfile.NamedTemporaryFile("w", prefix="hritest-error-", suffix=".log", delete=False) as log:
            log.write("".join(traceback.format_exception(exc)))
        path = log.name
    last = traceback.format_exception_only(exc)[-1].strip()
    err.print(
        f"hritest failed ({last}). This is a bug in hritest, not in your spec or plugins; the traceback is "
        f"in {path}. Please report it with that file (hritest {hritest.__version__}).",
        markup=False,
        highlight=False,
    )


def _version(value: bool) -> None:
    if value:
        out.print(f"hritest {hritest.__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="print the version and exit")
    ] = False,
) -> None:
    """Find where a robot policy fails with people, and keep those failures as tests."""


@command
def validate(specs: Annotated[list[Path], typer.Argument(help="one or more spec files")]) -> None:
    """Check specs: schema, names, plugins, expressions. Prints every problem with file:line:column."""
    from hritest.domain import load_domain

    bad = 0
    for path in specs:
        try:
            load_domain(path)
        except HritestError as exc:
            bad += 1
            err.print(f"[red]invalid[/red] {path}", highlight=False)
            err.print(str(exc), markup=False, highlight=False)
        else:
            out.print(f"[green]ok[/green] {path}", highlight=False)
    if bad:
        raise typer.Exit(ExitCode.INPUT)


@command
def check(
    spec: SpecArg,
    scenarios: Annotated[int, typer.Option(min=0, help="random scenarios to try besides the nominal one")] = 3,
    seed: Annotated[int, typer.Option(help="seed of the scenarios tried")] = 0,
) -> None:
    """Try a spec and its plugins before a search: exit 0 when ready, 2 with what to fix.

    Compiles the spec, runs the nominal scenario (twice, for determinism) and a few random ones,
    checks each rollout against the plugin contract, and says what one scenario costs.
    """
    from hritest.check import check_spec
    from hritest.errors import SpecError

    try:
        report = check_spec(spec, scenarios=scenarios, seed=seed)
    except SpecError as exc:
        err.print(f"[red]x[/red] {spec} does not compile:", highlight=False)
        err.print(str(exc), markup=False, highlight=False)
        raise typer.Exit(ExitCode.INPUT) from None
    for line in report.passed:
        out.print(f"[green]ok[/green] {escape(line)}", highlight=False)
    for note in report.notes:
        out.print(f"[yellow]note[/yellow] {escape(note)}", highlight=False)
    per = report.seconds_per_scenario
    out.print(
        f"one scenario takes {_duration(per)} (median of {len(report.seconds)}); the spec's budget of "
        f"{report.budget} evaluations is about {_duration(per * report.budget)} of simulation on one worker",
        highlight=False,
    )
    for finding in report.findings:
        err.print(f"[red]x[/red] {escape(str(finding))}", highlight=False)
    if not report.ok:
        err.print(f"{len(report.findings)} finding(s): fix them before a search.", highlight=False)
        raise typer.Exit(ExitCode.INPUT)
    out.print(f"{spec}: ready to search.", highlight=False)


def _duration(seconds: float) -> str:
    for unit, size in (("h", 3600.0), ("min", 60.0), ("s", 1.0)):
        if seconds >= size:
            return f"{seconds / size:.3g} {unit}"
    return f"{seconds * 1000:.3g} ms"


@command
def show(spec: SpecArg) -> None:
    """Print the compiled scenario space (theta layout, bounds), archive, policies and failure condition."""
    from hritest.domain import compile_spec
    from hritest.spec import load_spec

    domain = compile_spec(load_spec(spec))
    s = domain.spec
    out.print(f"[bold]{s.name}[/bold]  {s.description}".rstrip(), highlight=False)
    out.print(
        f"task {s.task.name} ({domain.task_cls.__name__}), time limit {s.task.time_limit:g} s, tick {s.task.dt:g} s",
        highlight=False,
    )
    out.print(
        f"robot {s.robot.policy} ({domain.robot_cls.__name__}), human {s.human.policy} ({domain.human_cls.__name__})",
        highlight=False,
    )

    table = Table(title=f"theta: {domain.space.dim} components", title_justify="left")
    for column in ("index", "component", "binds", "lower", "upper"):
        table.add_column(column, justify="right" if column in ("index", "lower", "upper") else "left")
    for slot in domain.space.slots:
        for i, label in enumerate(slot.labels):
            table.add_row(str(slot.start + i), label, slot.bind, f"{slot.lower:g}", f"{slot.upper:g}")
    out.print(table)

    cells = (
        f"a cvt archive of {domain.archive_cells:,} cells"
        if s.archive.type == "cvt"
        else " x ".join(map(str, domain.archive_dims)) + " cells"
    )
    archive = Table(title=f"result archive: {cells}", title_justify="left")
    for column in ("measure", "expression", "range", "cells"):
        archive.add_column(column)
    for m in domain.measures:
        archive.add_row(m.name, m.expression.text, f"[{m.range[0]:g}, {m.range[1]:g}]", str(m.cells or "—"))
    out.print(archive)
    out.print(
        f"objective {s.objective.expr} in [{s.objective.range[0]:g}, {s.objective.range[1]:g}] "
        f"(search subtracts {s.objective.repair_weight:g} x repair cost)",
        highlight=False,
    )
    out.print(f"failure when {s.failure}", highlight=False)
    for c in s.constraints:
        out.print("constraint " + ", ".join(f"{k}={v}" for k, v in c.model_dump().items()), highlight=False)
    out.print(f"search {s.search.algorithm}, budget {s.search.budget}, seed {s.search.seed}", highlight=False)


ThetaOption = Annotated[
    str, typer.Option("--theta", help="comma-separated theta, in the order 'hritest show' lists", show_default=False)
]
JsonOption = Annotated[bool, typer.Option("--json", help="print JSON instead of a table")]


def _domain_and_theta(spec: Path, theta: str):  # noqa: ANN202 - (Domain, np.ndarray)
    import numpy as np

    from hritest.domain import compile_spec
    from hritest.spec import load_spec

    domain = compile_spec(load_spec(spec))
    try:
        values = np.array([float(v) for v in theta.replace(" ", "").split(",")])
    except ValueError:
        raise typer.BadParameter(
            f"{theta!r} is not a comma-separated list of numbers (no slot may be empty)", param_hint="--theta"
        ) from None
    if not np.all(np.isfinite(values)):
        raise typer.BadParameter(f"{theta!r}: every value must be a finite number", param_hint="--theta")
    if values.shape != (domain.space.dim,):
        raise typer.BadParameter(
            f"got {len(values)} values; {spec} needs {domain.space.dim}: {', '.join(domain.space.labels)}",
            param_hint="--theta",
        )
    return domain, values


def _print_json(data: dict) -> None:
    import json

    print(json.dumps(data, indent=2, default=float))


@command
def repair(spec: SpecArg, theta: ThetaOption, json: JsonOption = False) -> None:
    """Repair one scenario: where its objects move to satisfy the constraints, and at what cost."""
    domain, values = _domain_and_theta(spec, theta)
    outcome = domain.repair(values)
    data = {
        "status": outcome.status,
        "theta": values.tolist(),
        "repaired": outcome.theta.tolist(),
        "cost": outcome.cost,
        "regions": outcome.regions,
        "message": outcome.message,
    }
    if json:
        _print_json(data)
    else:
        table = Table(title=f"repair: {outcome.status}, cost {outcome.cost:.6g}", title_justify="left")
        for column in ("component", "given", "repaired", "moved"):
            table.add_column(column, justify="left" if column == "component" else "right")
        for label, a, b in zip(domain.space.labels, values, outcome.theta):
            table.add_row(label, f"{a:.6g}", f"{b:.6g}", f"{b - a:+.3g}" if b != a else "")
        out.print(table)
        for name, region in outcome.regions.items():
            out.print(f"{name} placed in {region}", highlight=False)
        if outcome.message:
            out.print(outcome.message, highlight=False)
    if not outcome.ok:
        raise typer.Exit(ExitCode.FINDING)


@command
def simulate(
    spec: SpecArg,
    theta: ThetaOption,
    seed: Annotated[int, typer.Option(help="the evaluation seed")] = 0,
    json: JsonOption = False,
) -> None:
    """Simulate one scenario: status, objective, measures and every metric.

    Exit 1 if it is a failure, 3 if it could not be evaluated (its status says why).
    """
    from hritest.evaluate import evaluate
    from hritest.records import clauses_text

    domain, values = _domain_and_theta(spec, theta)
    with contextlib.redirect_stdout(sys.stderr):  # what a plugin prints must not break --json
        evaluation = evaluate(domain, values, seed=seed)
    data = {
        "status": evaluation.status,
        "failure": evaluation.failure,
        "clauses": [c.to_json() for c in evaluation.clauses],
        "objective": evaluation.objective,
        "search_objective": evaluation.search_objective,
        "measures": dict(zip((m.name for m in domain.measures), evaluation.measures.tolist())),
        "metrics": evaluation.metrics,
        "theta": values.tolist(),
        "theta_repaired": evaluation.theta_repaired.tolist(),
        "repair_cost": evaluation.repair_cost,
        "regions": evaluation.regions,
        "seed": seed,
        "seconds": evaluation.seconds,
        "message": evaluation.message,
    }
    if json:
        _print_json(data)
    else:
        verdict = "[red]FAILURE[/red]" if evaluation.failure else "[green]no failure[/green]"
        out.print(f"{evaluation.status}: {verdict} ({domain.spec.failure}), simulated in {evaluation.seconds:.3f} s")
        if evaluation.fired:
            out.print(f"why: {escape(clauses_text(evaluation.fired))}", highlight=False)
        table = Table(show_header=False)
        rows = [
            ("objective", evaluation.objective),
            ("search objective", evaluation.search_objective),
            ("repair cost", evaluation.repair_cost),
            *data["measures"].items(),
            *evaluation.metrics.items(),
        ]
        for name, value in rows:
            table.add_row(name, f"{value:.6g}")
        out.print(table)
        if evaluation.message:
            err.print(evaluation.message, markup=False, highlight=False)
    if not evaluation.ok:
        raise typer.Exit(ExitCode.INCOMPLETE)
    if evaluation.failure:
        raise typer.Exit(ExitCode.FINDING)


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
        typer.Option(help="random, map_elites, cma_mae, sas, dsas (default: the spec's)", rich_help_panel="Search"),
    ] = None,
    budget: Annotated[
        int | None, typer.Option(min=1, help="real evaluations (default: the spec's)", rich_help_panel="Search")
    ] = None,
    seed: Annotated[int | None, typer.Option(help="default: the spec's", rich_help_panel="Search")] = None,
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
    with _Progress(quiet) as progress:
        if resume is not None:
            found = qd.resume(run_path=resume, backend=backend, progress=progress, trust=trust)
        else:
            found = qd.start(
                spec_file=spec,
                out=out_dir,
                algorithm=algorithm,
                budget=budget,
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
    if not any(r.ok for r in found.records.values()):
        err.print(
            f"no evaluation completed: see the status and message of each in {found.run_dir.path / 'evaluations.jsonl'}"
            " (try one with 'hritest simulate')",
            markup=False,
            highlight=False,
        )
        raise typer.Exit(ExitCode.INCOMPLETE)
    if found.failures():
        raise typer.Exit(ExitCode.FINDING)


class _Progress:
    """Search progress on stderr: a bar that fits the terminal on one; without one (a CI log), a
    plain line when the search starts, every ``PLAIN_SECONDS`` while it runs (whatever it is
    doing, a long surrogate training included) and when it ends; nothing with ``quiet``."""

    PLAIN_SECONDS = 5.0

    def __init__(self, quiet: bool) -> None:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
        from rich.table import Column

        self.plain = not quiet and not err.is_terminal
        self.bar = (
            None
            if quiet or self.plain
            else Progress(
                # One line at any width: the bar and the numbers share what the counts leave.
                TextColumn("[bold]search", table_column=Column(no_wrap=True)),
                BarColumn(bar_width=None, table_column=Column(ratio=1, min_width=5)),
                MofNCompleteColumn(table_column=Column(no_wrap=True)),
                TextColumn("{task.fields[stats]}", table_column=Column(ratio=3, no_wrap=True, overflow="ellipsis")),
                TimeRemainingColumn(table_column=Column(no_wrap=True)),
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

    def __enter__(self):  # noqa: ANN204
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
            self.task = self.bar.add_task("search", total=snapshot.budget, stats="")
        self.bar.update(self.task, completed=snapshot.evaluations, stats=self._stats(snapshot))

    def _tick(self) -> None:
        while not self.stop.wait(self.PLAIN_SECONDS):
            if self.snapshot is not None:
                self._print_line()

    def _print_line(self) -> None:
        snapshot = self.snapshot
        started, evaluations = self.first
        rate = (snapshot.evaluations - evaluations) / max(time.monotonic() - started, 1e-9)
        err.print(
            f"search: {snapshot.evaluations}/{snapshot.budget} evaluations, {self._stats(snapshot)}, "
            f"{rate:.3g} evaluations/s",
            markup=False,
            highlight=False,
        )

    @staticmethod
    def _stats(snapshot) -> str:  # noqa: ANN001 - hritest.search.Snapshot
        s = snapshot.summary
        parts = [
            f"QD-score {s.qd_score:,.1f}, coverage {s.coverage:.1%}" if s else "QD-score -",
            f"failures {snapshot.failures}",
            f"did not complete {snapshot.failed}",
            snapshot.phase,
        ]
        return ", ".join(parts)


def _print_summary(found) -> None:  # noqa: ANN001 - hritest.search.Search
    from hritest.search.archives import Summary

    state = found.state
    summary = Summary.of(state.result, found.domain.spec.objective.range)
    statuses: dict[str, int] = {}
    for record in found.records.values():
        statuses[record["status"]] = statuses.get(record["status"], 0) + 1
    table = Table(
        title=f"{found.domain.spec.name}: {state.algorithm}, seed {state.seed}",
        title_justify="left",
        show_header=False,
    )
    rows = [
        ("run directory", str(found.run_dir.path)),
        ("evaluations", f"{state.evaluations} ({', '.join(f'{n} {k}' for k, n in sorted(statuses.items()))})"),
        ("wall time", f"{state.elapsed:.1f} s"),
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
) -> None:
    """Write a run's failure report (report/index.html and summary.md) and its failures' Rerun recordings.

    With several runs, write one page that compares them (no recordings).
    """
    from hritest.report import compare_runs, write_report

    if len(runs) == 1:
        page = write_report(runs[0], recordings=recordings, out=out_dir)
        folder = runs[0] / "recordings"
        if folder.is_dir() and recordings:
            out.print(f"recordings: {folder}", highlight=False)
    else:
        page = compare_runs(runs, out_dir if out_dir is not None else Path("report-compare"))
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
    seed: Annotated[int, typer.Option(help="the evaluation seed, with a SPEC")] = 0,
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
    if target.is_dir():
        if failure is None or theta is not None:
            raise typer.BadParameter("with a run directory give --failure ID (and no --theta)", param_hint="--failure")
        run = RunDirectory.open(target)
        record = rp.stored_failure(run, failure)  # bad input fails before anything is written
        path = recording.check_writable(out_path or run.path / "recordings" / f"{failure}.rrd")
        result = rp.replay_record(rp.run_domain(run), record, spec_digest=run.meta["spec_digest"], tolerance=tolerance)
        title = f"{result.domain.spec.name}: failure {failure} ({run.path.resolve().name})"
    elif hc.is_entry(target):
        if failure is not None or theta is not None:
            raise typer.BadParameter(
                "a corpus entry replays its own theta and seed: give neither", param_hint="--theta"
            )
        path = recording.check_writable(out_path or Path("recordings") / f"{target.stem}.rrd")
        result = rp.replay_entry(target, tolerance=tolerance)
        title = f"{result.domain.spec.name}: corpus entry {target.stem}"
    else:
        if theta is None or failure is not None:
            raise typer.BadParameter("with a spec give --theta v1,v2,... (and no --failure)", param_hint="--theta")
        domain, values = _domain_and_theta(target, theta)
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
        _print_json({"failure": failure, **result.to_json()})
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

    def show(value) -> str:  # noqa: ANN001
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

    if run is None and not mark_fixed:
        raise typer.BadParameter("give a RUN directory to promote from, or --mark-fixed ID (or both)")
    folder = to if to is not None else hc.default_corpus(Path.cwd())
    if run is not None:
        if mark_fixed and not run.is_dir():
            raise HritestError(
                f"{run} is not a run directory; to mark several entries fixed repeat the "
                "option: --mark-fixed ID --mark-fixed ID"
            )
        promoted = hc.promote(run, corpus=folder, top=top)
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


@command
def new(
    name: Annotated[
        str,
        typer.Argument(help="the domain's name: letters, digits and '_', starting with a letter", show_default=False),
    ],
    folder: Annotated[Path, typer.Option("--dir", help="where to write NAME.yaml and NAME_plugins.py")] = Path("."),
) -> None:
    """Start a domain: write NAME.yaml and NAME_plugins.py, a minimal spec and plugins that work as written.

    Never overwrites: exit 2 if either file exists, or if NAME is not a valid name.
    """
    from hritest.scaffold import write_domain

    spec, plugins = write_domain(name, folder=folder)
    out.print(f"wrote {spec} and {plugins}", highlight=False)
    out.print(f"next: hritest check {spec}, then hritest search {spec} --budget 200", highlight=False)


if __name__ == "__main__":
    app()
