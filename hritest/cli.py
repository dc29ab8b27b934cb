"""The ``hritest`` command line. Exit codes: 0 ok, 1 a finding or failure, 2 usage or input error."""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

import hritest
from hritest.errors import HritestError

app = typer.Typer(
    no_args_is_help=True,
    add_completion=False,
    help="Find where a robot policy fails with people, and keep those failures as tests.",
    pretty_exceptions_enable=False,
)
out = Console(soft_wrap=True)
err = Console(stderr=True, soft_wrap=True)

EXIT_OK, EXIT_FINDING, EXIT_INPUT = 0, 1, 2

SpecArg = Annotated[Path, typer.Argument(help="a hritest spec (YAML)", show_default=False)]


def command(fn):  # noqa: ANN001, ANN201 - a typer command
    """Registers ``fn`` as a command; hritest's own errors become one message and exit code 2."""

    @functools.wraps(fn)
    def run(*args, **kwargs):  # noqa: ANN202
        try:
            return fn(*args, **kwargs)
        except HritestError as exc:
            err.print(str(exc), markup=False, highlight=False)
            raise typer.Exit(EXIT_INPUT) from None

    return app.command()(run)


def _version(value: bool) -> None:
    if value:
        out.print(f"hritest {hritest.__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[bool, typer.Option("--version", callback=_version, is_eager=True,
                                          help="print the version and exit")] = False,
) -> None:
    """Find where a robot policy fails with people, and keep those failures as tests."""


@command
def validate(specs: Annotated[list[Path], typer.Argument(help="one or more spec files")]) -> None:
    """Check specs: schema, names, plugins, expressions. Prints every problem with file:line:column."""
    from hritest.domain import compile_spec
    from hritest.spec import load_spec

    bad = 0
    for path in specs:
        try:
            compile_spec(load_spec(path))
        except HritestError as exc:
            bad += 1
            err.print(f"[red]invalid[/red] {path}", highlight=False)
            err.print(str(exc), markup=False, highlight=False)
        else:
            out.print(f"[green]ok[/green] {path}", highlight=False)
    if bad:
        raise typer.Exit(EXIT_INPUT)


@command
def show(spec: SpecArg) -> None:
    """Print the compiled scenario space (theta layout, bounds), archive, policies and failure condition."""
    from hritest.domain import compile_spec
    from hritest.spec import load_spec

    domain = compile_spec(load_spec(spec))
    s = domain.spec
    out.print(f"[bold]{s.name}[/bold]  {s.description}".rstrip(), highlight=False)
    out.print(f"task {s.task.name} ({domain.task_cls.__name__}), time limit {s.task.time_limit:g} s, "
              f"tick {s.task.dt:g} s", highlight=False)
    out.print(f"robot {s.robot.policy} ({domain.robot_cls.__name__}), "
              f"human {s.human.policy} ({domain.human_cls.__name__})", highlight=False)

    table = Table(title=f"theta: {domain.space.dim} components", title_justify="left")
    for column in ("index", "component", "binds", "lower", "upper"):
        table.add_column(column, justify="right" if column in ("index", "lower", "upper") else "left")
    for slot in domain.space.slots:
        for i, label in enumerate(slot.labels):
            table.add_row(str(slot.start + i), label, slot.bind, f"{slot.lower:g}", f"{slot.upper:g}")
    out.print(table)

    archive = Table(title="result archive: " + " x ".join(map(str, domain.archive_dims)) + " cells",
                    title_justify="left")
    for column in ("measure", "expression", "range", "cells"):
        archive.add_column(column)
    for m in domain.measures:
        archive.add_row(m.name, m.expression.text, f"[{m.range[0]:g}, {m.range[1]:g}]", str(m.cells))
    out.print(archive)
    out.print(f"objective {s.objective.expr} in [{s.objective.range[0]:g}, {s.objective.range[1]:g}] "
              f"(search subtracts {s.objective.repair_weight:g} x repair cost)", highlight=False)
    out.print(f"failure when {s.failure}", highlight=False)
    for c in s.constraints:
        out.print("constraint " + ", ".join(f"{k}={v}" for k, v in c.model_dump().items()), highlight=False)
    out.print(f"search {s.search.algorithm}, budget {s.search.budget}, seed {s.search.seed}", highlight=False)
