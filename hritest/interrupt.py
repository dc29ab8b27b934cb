"""Stopping hritest on SIGINT (Ctrl-C) or SIGTERM without tearing a search's run directory.

While :func:`stop_on_signals` is active, either signal raises :class:`Interrupted` in the main
thread, except inside :func:`deferred` blocks (the writes a resume reads: an evaluation's record,
a checkpoint), where it is held until the block ends. So a stopped search leaves whole files,
and ``--resume`` continues from them. :class:`Interrupted` is not a KeyboardInterrupt, so that
code which contains a plugin's KeyboardInterrupt (see :mod:`hritest.evaluate`) never contains a
real Ctrl-C.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(BaseException):
    """The user (SIGINT) or the system (SIGTERM) stopped hritest.

    Attributes:
        signum: the signal received.
        run: the run directory the search was writing, once known (for how to resume).
    """

    def __init__(self, signum: int, run: Path | None = None) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum, self.run = signum, run

    @property
    def exit_code(self) -> int:
        """The shell's convention for a process ended by a signal: 128 + its number."""
        return 128 + self.signum


class _Held:
    """The signal received inside a deferred block, and how deep the blocks are nested."""

    depth = 0
    signum: int | None = None


_held = _Held()


def _handle(signum: int, frame: object) -> None:
    if _held.depth:
        _held.signum = _held.signum or signum
        return
    raise Interrupted(signum)


@contextmanager
def stop_on_signals() -> Iterator[None]:
    """SIGINT and SIGTERM raise :class:`Interrupted` for the duration (main thread only; elsewhere
    Python cannot install handlers, and the caller's own stay)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.signal(s, _handle) for s in SIGNALS}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


@contextmanager
def deferred() -> Iterator[None]:
    """Holds a signal received in the block until it ends, then raises it."""
    _held.depth += 1
    try:
        yield
    finally:
        _held.depth -= 1
        if not _held.depth and _held.signum is not None:
            signum, _held.signum = _held.signum, None
            raise Interrupted(signum)


def ignore_in_worker() -> None:
    """A pool worker ignores Ctrl-C: the terminal sends it to the whole process group, and the
    parent, which owns the run directory, decides how to stop (it stops its workers itself)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
