"""The ``hritest`` command line's frame: the typer app, its consoles, what every command shares,
and :class:`ExitCode`, the same for every command. The commands live in :mod:`.specs` (on a
spec) and :mod:`.runs` (searching and what comes of it)."""

from __future__ import annotations

import functools
import signal
import tempfile
import traceback
from enum import IntEnum
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

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
    def run(*args: object, **kwargs: object) -> object:
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


ThetaOption = Annotated[
    str, typer.Option("--theta", help="comma-separated theta, in the order 'hritest show' lists", show_default=False)
]
JsonOption = Annotated[bool, typer.Option("--json", help="print JSON instead of a table")]


def domain_and_theta(spec: Path, theta: str):  # noqa: ANN201 - (Domain, np.ndarray): both imported lazily
    import numpy as np

    from hritest.domain import load_domain

    domain = load_domain(spec)
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


_UNITS = {"": 1, "s": 1, "m": 60, "h": 3600}


def duration(text: str) -> float:
    """Seconds in ``90``, ``90s``, ``15m``, ``2h`` or ``1.5h``: what ``--time-limit`` takes."""
    import math

    number, unit = text.strip().lower(), ""
    if number[-1:] in _UNITS:
        number, unit = number[:-1], number[-1]
    try:
        seconds = float(number) * _UNITS[unit]
    except ValueError:
        seconds = math.nan
    if not 0 < seconds < math.inf:
        raise typer.BadParameter(
            f"{text!r} is not a duration above zero; write seconds (90 or 90s), minutes (15m) or hours (2h)"
        )
    return seconds


def print_json(data: dict) -> None:
    import json

    print(json.dumps(data, indent=2, default=float))
