"""The commands on a spec: validate, check, show, repair, simulate, and new (a spec to start from)."""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape
from rich.table import Table

from hritest.cli.app import (
    ExitCode,
    JsonOption,
    SpecArg,
    ThetaOption,
    command,
    domain_and_theta,
    err,
    out,
    print_json,
)
from hritest.errors import HritestError
from hritest.records import MAX_SEED


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
    seed: Annotated[int, typer.Option(min=0, max=MAX_SEED, help="seed of the scenarios tried")] = 0,
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
    from hritest.domain import load_domain

    domain = load_domain(spec)
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
        f"(search subtracts {s.objective.repair_weight:g} x repair cost, in {s.repair.units} units)",
        highlight=False,
    )
    out.print(f"failure when {s.failure}", highlight=False)
    for c in s.constraints:
        out.print("constraint " + ", ".join(f"{k}={v}" for k, v in c.model_dump().items()), highlight=False)
    out.print(f"search {s.search.algorithm}, budget {s.search.budget}, seed {s.search.seed}", highlight=False)


@command
def repair(spec: SpecArg, theta: ThetaOption, json: JsonOption = False) -> None:
    """Repair one scenario: where its objects move to satisfy the constraints, and at what cost."""
    domain, values = domain_and_theta(spec, theta)
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
        print_json(data)
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
    seed: Annotated[int, typer.Option(min=0, max=MAX_SEED, help="the evaluation seed")] = 0,
    json: JsonOption = False,
) -> None:
    """Simulate one scenario: status, objective, measures and every metric.

    Exit 1 if it is a failure, 3 if it could not be evaluated (its status says why).
    """
    from hritest.evaluate import evaluate
    from hritest.records import clauses_text

    domain, values = domain_and_theta(spec, theta)
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
        print_json(data)
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
