"""hritest's pytest plugin: the failure corpus replays as regression tests.

Registered through the ``pytest11`` entry point, so pytest imports this module in *every* run of
every project where hritest is installed. It therefore imports only the standard library, pytest and
:mod:`hritest.corpus` at module level; the simulator, the repair solver and the rest load the first
time a corpus entry (or the ``hri_scenario`` fixture) actually runs.

Each corpus file ``<corpus>/<spec>/<id>.yaml`` becomes one test, ``<file>::<spec>::<id>``, that
re-simulates the stored scenario with the current plugins, in a worker process with a time limit
(:mod:`hritest.corpus_worker`), and is judged by :func:`hritest.verdict.judge`. This module only
maps verdicts to pytest outcomes:

=================  ==========================================
verdict            reported as
=================  ==========================================
passing            passed
regression         FAILED
still failing      xfailed
flaky              xfailed, with its failure rate
now passing        XPASS
error              FAILED (never a pass or a skip)
=================  ==========================================

An entry is replayed whatever changed since it was recorded; what changed is shown beside its verdict.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from hritest import corpus as hc
from hritest.errors import HritestError
from hritest.pytest_fixture import hri_scenario  # noqa: F401 - a fixture: pytest finds it in this plugin

# The summary's order; the first four are always counted.
OUTCOMES = ("regression", "still failing", "now passing", "flaky", "passing", "error", "search with new failures")

_corpus_key = pytest.StashKey[Path]()
_worker_key = pytest.StashKey[Any]()


# --- options, configuration, header --------------------------------------------------------------


def pytest_addoption(parser: pytest.Parser) -> None:
    from hritest.corpus_worker import COMPILE_SECONDS  # which imports only what this module does

    group = parser.getgroup("hritest", "hritest failure corpus")
    group.addoption(
        "--hri-corpus",
        metavar="DIR",
        default=None,
        help="the failure corpus to replay (default: [tool.hritest] corpus in pyproject.toml, "
        "else tests/hri_failures; relative to the rootdir)",
    )
    group.addoption(
        "--hri-spec",
        metavar="SPEC",
        action="append",
        default=[],
        help="replay only the entries of this spec (its name or its file); repeatable",
    )
    group.addoption(
        "--hri-mark-fixed",
        action="store_true",
        default=False,
        help="set status: fixed in the corpus files of open failures that no longer fail",
    )
    group.addoption(
        "--hri-replays",
        metavar="N",
        type=int,
        default=1,
        help="replay each entry with N seeds, the recorded one first; an open entry that fails with only "
        "some is reported as flaky, a fixed one that fails with any is a regression",
    )
    group.addoption(
        "--hri-timeout",
        metavar="S",
        type=float,
        default=None,
        help="the time limit of one replay in seconds (default: 5 x the seconds the entry recorded + 30); "
        "an entry that takes longer fails",
    )
    group.addoption(
        "--hri-compile-timeout",
        metavar="S",
        type=float,
        default=COMPILE_SECONDS,
        help=f"the time limit in seconds of compiling an entry's spec, once per spec, in the replay process "
        f"(default: {COMPILE_SECONDS:g}: plugin imports and a first numba compile); the entries of a spec "
        "that takes longer fail",
    )
    group.addoption(
        "--hri-allow-outside",
        action="store_true",
        default=False,
        help="replay entries whose spec lies outside the rootdir (compiling it runs the plugins it names)",
    )
    group.addoption(
        "--hri-search-budget",
        metavar="N",
        type=int,
        default=0,
        help="also run a Random search of N evaluations per spec in the corpus (the spec's seed); "
        "a failure it finds that the corpus does not hold fails the session",
    )


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "hri: a hritest scenario test (a failure corpus entry or a test using the hri_scenario fixture)"
    )
    given = config.getoption("hri_corpus", None)
    replays = config.getoption("hri_replays", 1)
    if replays < 1:
        raise pytest.UsageError(f"--hri-replays must be 1 or more, got {replays}")
    for option in ("hri_timeout", "hri_compile_timeout"):
        timeout = config.getoption(option, None)
        if timeout is not None and not 0 < timeout < float("inf"):
            name = "--" + option.replace("_", "-")
            raise pytest.UsageError(f"{name} must be a positive number of seconds, got {timeout}")
    try:
        corpus = (config.rootpath / given) if given else hc.default_corpus(config.rootpath)
    except hc.CorpusError as exc:
        raise pytest.UsageError(str(exc)) from None
    if given and not corpus.is_dir():
        raise pytest.UsageError(
            f"--hri-corpus {given}: {corpus} is not a folder (the path is relative to the rootdir "
            f"{config.rootpath}); give the folder that holds <spec>/<id>.yaml entries"
        )
    config.stash[_corpus_key] = corpus = corpus.resolve()
    config.pluginmanager.register(_Summary(config), "hritest-summary")
    # A corpus outside the paths pytest collects (testpaths, say) is still replayed when no path was
    # given, or when --hri-corpus names it.
    explicit = config.args_source == pytest.Config.ArgsSource.ARGS
    if corpus.is_dir() and (given or not explicit) and not _covered(corpus, config):
        config.args.append(str(corpus))


def _covered(corpus: Path, config: pytest.Config) -> bool:
    for arg in config.args:
        path = Path(config.invocation_params.dir, arg.split("::")[0]).resolve()
        if path == corpus or path in corpus.parents:
            return True
    return False


def pytest_unconfigure(config: pytest.Config) -> None:
    worker = config.stash.get(_worker_key, None)
    if worker is not None:
        worker.close()


def pytest_report_header(config: pytest.Config) -> str | None:
    corpus = config.stash.get(_corpus_key, None)
    if corpus is None or not corpus.is_dir():
        return None
    count = len(hc.entry_files(corpus))
    return f"hritest: failure corpus {_shown(corpus, config)} ({count} entr{'y' if count == 1 else 'ies'})"


def _shown(path: Path, config: pytest.Config) -> str:
    try:
        return str(path.relative_to(config.rootpath))
    except ValueError:
        return str(path)


# --- collection ---------------------------------------------------------------------------------


def pytest_collect_file(file_path: Path, parent: pytest.Collector) -> pytest.Collector | None:
    corpus = parent.config.stash.get(_corpus_key, None)
    if corpus is not None and file_path.suffix in (".yaml", ".yml") and corpus in file_path.resolve().parents:
        return CorpusFile.from_parent(parent, path=file_path)
    return None


class CorpusFile(pytest.File):
    """One corpus file; a malformed or misplaced one is a collection error naming the file and the field."""

    def collect(self) -> Iterator[pytest.Collector]:
        misplaced = hc.misplaced(self.config.stash[_corpus_key], self.path)
        if misplaced:
            raise self.CollectError(f"hritest corpus: {misplaced}")
        try:
            entry = hc.load_entry(self.path)
        except hc.CorpusError as exc:
            raise self.CollectError(f"hritest corpus: {exc}") from None
        yield CorpusSpec.from_parent(self, name=entry.spec_name, entry=entry)


class CorpusSpec(pytest.Collector):
    """The spec level of ``<file>::<spec>::<id>``, so that ``-k <spec>`` and node ids both work."""

    def __init__(self, *, entry: hc.Entry, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.entry = entry

    def collect(self) -> Iterator[pytest.Item]:
        yield CorpusItem.from_parent(self, name=self.entry.id, entry=self.entry)


class HriFailure(Exception):  # noqa: N818 - a test failure, reported as one
    """A failure marked fixed that fails again (or an entry that no longer evaluates)."""


class CorpusItem(pytest.Item):
    """One stored failure, re-simulated and judged by the spec's failure condition."""

    def __init__(self, *, entry: hc.Entry, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.entry = entry
        self.add_marker("hri")
        self.hri_outcome = ""  # set by runtest: one of OUTCOMES
        self.hri_section = ""  # the report's "hritest" section

    def runtest(self) -> None:
        from hritest.corpus_worker import replay_entry
        from hritest.verdict import Verdict

        entry, config = self.entry, self.config
        self.user_properties.append(("hri_entry", f"{entry.spec_name}/{entry.id}"))
        judged = replay_entry(
            entry,
            worker=_worker(config),
            replays=config.getoption("hri_replays"),
            timeout=config.getoption("hri_timeout"),
            compile_timeout=config.getoption("hri_compile_timeout"),
            project=None if config.getoption("hri_allow_outside") else config.rootpath,
        )
        verdict, changed = judged.verdict, (f" {judged.changed}" if judged.changes else "")
        if judged.changes:
            self.user_properties.append(("hri_changes", ", ".join(judged.changes)))
        if judged.failure_rate is not None and verdict is Verdict.FLAKY:
            self.user_properties.append(("hri_failure_rate", f"{judged.failure_rate:.0%}"))
        if verdict is Verdict.ERROR:
            self._set(verdict, "")
            raise HriFailure(f"{self._title()} cannot be replayed: {judged.reason}{changed}")
        if verdict is Verdict.REGRESSION:
            self._set(verdict, "")
            raise HriFailure(f"{self._title()} {judged.reason}{changed}\n{judged.detail}")
        if verdict in (Verdict.STILL_FAILING, Verdict.FLAKY):
            self._set(verdict, judged.detail)
            rate = f" (flaky: fails {judged.failure_rate:.0%} of its replays)" if verdict is Verdict.FLAKY else ""
            pytest.xfail(f"hritest open failure{rate} {judged.reason}{changed}")
        if verdict is Verdict.PASSING:
            self._set(verdict, judged.changed)
            return
        text = f"open failure {entry.spec_name}/{entry.id} {judged.reason}{changed}\n{judged.detail}\n"
        if config.getoption("hri_mark_fixed"):
            hc.set_status(entry.path, "fixed")
            text += f"marked fixed in {entry.path} (--hri-mark-fixed)"
        else:
            text += (
                f"mark it fixed: hritest promote --to {_shown(entry.path.parent.parent, config)} "
                f"--mark-fixed {entry.spec_name}/{entry.id}   (or run pytest with --hri-mark-fixed)"
            )
        self._set(verdict, text)

    def _set(self, outcome: str, section: str) -> None:
        self.hri_outcome, self.hri_section = outcome, section
        self.user_properties.append(("hri_outcome", outcome))

    def _title(self) -> str:
        return f"hritest {self.entry.spec_name}/{self.entry.id}"

    def repr_failure(self, excinfo: pytest.ExceptionInfo[BaseException], style: Any = None) -> Any:
        if isinstance(excinfo.value, HriFailure):
            return f"{excinfo.value}\nreplay it: hritest replay {_shown(self.entry.path, self.config)}"
        if isinstance(excinfo.value, HritestError):
            return f"{self._title()}: {excinfo.value}"
        return super().repr_failure(excinfo)

    def reportinfo(self) -> tuple[os.PathLike[str] | str, int | None, str]:
        return self.path, None, f"hri {self.entry.spec_name}::{self.entry.id} ({self.entry.status})"


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if "hri_scenario" in getattr(item, "fixturenames", ()):
            item.add_marker("hri")
    _select_specs(config, items)
    _add_searches(config, items)


def _select_specs(config: pytest.Config, items: list[pytest.Item]) -> None:
    """With ``--hri-spec``: deselects the corpus entries of every other spec."""
    wanted = config.getoption("hri_spec")
    if not wanted:
        return
    files = {Path(config.invocation_params.dir, w).resolve() for w in wanted if w.endswith((".yaml", ".yml"))}
    keep, drop = [], []
    for item in items:
        if isinstance(item, CorpusItem) and not (item.entry.spec_name in wanted or item.entry.spec_path in files):
            drop.append(item)
        else:
            keep.append(item)
    if drop:
        config.hook.pytest_deselected(items=drop)
        items[:] = keep


def _add_searches(config: pytest.Config, items: list[pytest.Item]) -> None:
    """With ``--hri-search-budget``: one :class:`SearchItem` per spec, after that spec's entries."""
    budget = config.getoption("hri_search_budget")
    if budget <= 0:
        return
    by_spec: dict[Path, list[CorpusItem]] = {}
    for item in items:
        if isinstance(item, CorpusItem):
            by_spec.setdefault(item.entry.spec_path, []).append(item)
    for spec, entries in by_spec.items():
        last = items.index(entries[-1])
        folder = entries[0].parent.parent.parent  # the corpus's <spec> folder
        search = SearchItem.from_parent(folder, name="search", spec=spec, entries=entries, budget=budget)
        items.insert(last + 1, search)


class SearchItem(pytest.Item):
    """A short Random search of one spec: fails when it finds a failure the corpus does not hold."""

    def __init__(self, *, spec: Path, entries: list[CorpusItem], budget: int, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.spec, self.budget = spec, budget
        self.spec_name = entries[0].entry.spec_name
        self.held = {e.entry.scenario_digest for e in entries}
        self.add_marker("hri")

    def runtest(self) -> None:
        import shutil

        from hritest import search as qd

        if not self.spec.is_file():
            pytest.skip(f"hritest: its spec {_shown(self.spec, self.config)} no longer exists")
        run = _search_folder(self.config) / self.spec_name
        shutil.rmtree(run, ignore_errors=True)
        found = qd.start(
            spec_file=self.spec,
            out=run,
            algorithm="random",
            budget=self.budget,
            seed=None,
            backend=qd.Backend(workers=os.cpu_count() or 1),
        )
        from hritest.promote import new_failures

        new = new_failures(found, self.held)
        if new:
            self.user_properties += [
                ("hri_entry", f"{self.spec_name}/search"),
                ("hri_outcome", "search with new failures"),
            ]
            raise HriFailure(
                f"a Random search of {self.budget} evaluations found {len(new)} failure(s) of {self.spec_name} "
                f"that the corpus does not hold:\n"
                + "\n".join(new)
                + f"\nkeep them: hritest promote {_shown(run, self.config)} "
                f"--to {_shown(self.path.parent, self.config)}"
            )

    def repr_failure(self, excinfo: pytest.ExceptionInfo[BaseException], style: Any = None) -> Any:
        if isinstance(excinfo.value, HriFailure | HritestError):
            return str(excinfo.value)
        return super().repr_failure(excinfo)

    def reportinfo(self) -> tuple[os.PathLike[str] | str, int | None, str]:
        return self.path, None, f"hri search {self.spec_name} (budget {self.budget})"


def _search_folder(config: pytest.Config) -> Path:
    """Where searches leave their run directories: pytest's cache folder, so one can promote from them."""
    cache = getattr(config, "cache", None)
    if cache is not None:
        return cache.mkdir("hritest-search")
    import tempfile

    return Path(tempfile.mkdtemp(prefix="hritest-search-"))


# --- replay -------------------------------------------------------------------------------------


def _worker(config: pytest.Config) -> Any:
    """The session's replay worker (:class:`hritest.corpus_worker.ReplayWorker`), closed at the end."""
    worker = config.stash.get(_worker_key, None)
    if worker is None:
        import sys

        from hritest.corpus_worker import ReplayWorker

        worker = config.stash[_worker_key] = ReplayWorker(cwd=config.rootpath, pythonpath=[p for p in sys.path if p])
    return worker


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Any:
    report = yield
    if isinstance(item, CorpusItem) and call.when == "call" and item.hri_outcome:
        if item.hri_section:
            report.sections.append(("hritest", item.hri_section))
        if item.hri_outcome == "now passing" and report.passed:
            was = f"; it failed: {'; '.join(item.entry.why)}" if item.entry.why else ""
            report.wasxfail = f"hritest open failure no longer fails ({item.entry.path.name}){was}"
    return report


# --- summary ------------------------------------------------------------------------------------


class _Summary:
    """Counts the corpus tests' outcomes from their reports (so it also works under pytest-xdist)
    and writes the ``hritest`` section of the terminal summary. One per pytest config."""

    def __init__(self, config: pytest.Config) -> None:
        self.config = config
        self.results: dict[str, list[tuple[str, str]]] = {}
        self.notes: dict[str, str] = {}  # entry -> its failure rate and what changed since it was recorded

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        props = dict(report.user_properties)
        if report.when != "call" or "hri_entry" not in props:
            return
        outcome = props.get("hri_outcome") or ("error" if report.failed else "")
        if outcome:
            self.results.setdefault(outcome, []).append((props["hri_entry"], report.nodeid))
        notes = [f"fails {props['hri_failure_rate']} of its replays"] if "hri_failure_rate" in props else []
        notes += [f"changed since recorded: {props['hri_changes']}"] if "hri_changes" in props else []
        if notes:
            self.notes[props["hri_entry"]] = "; ".join(notes)

    def pytest_terminal_summary(self, terminalreporter: Any) -> None:
        results, config, tr = self.results, self.config, terminalreporter
        if not results:
            return
        corpus = _shown(config.stash[_corpus_key], config)
        tr.ensure_newline()
        tr.section("hritest")
        counts = [_count(len(results.get(o, [])), o) for o in OUTCOMES[:4]]
        counts += [_count(len(results[o]), o) for o in OUTCOMES[4:] if results.get(o)]
        tr.write_line(f"corpus {corpus}: {', '.join(counts)}")
        for label, outcome in (("REGRESSION", "regression"), ("ERROR", "error"), ("FLAKY", "flaky")):
            for entry, nodeid in results.get(outcome, []):
                note = f"{self.notes[entry]}; " if entry in self.notes else ""
                tr.write_line(f"{label:<11} {entry}  ({note}{nodeid})")
        for entry, nodeid in results.get("search with new failures", []):
            tr.write_line(f"NEW         {entry}  (failures the corpus does not hold; {nodeid})")
        passing = results.get("now passing", [])
        if passing:
            done = config.getoption("hri_mark_fixed")
            tr.write_line("now passing (open failures that no longer fail" + (", marked fixed):" if done else "):"))
            for entry, nodeid in passing:
                tr.write_line(f"  {entry}  ({nodeid})")
            if not done:
                ids = " ".join(f"--mark-fixed {entry}" for entry, _ in passing)
                tr.write_line(f"mark them fixed: hritest promote --to {corpus} {ids}")
                tr.write_line("            or: pytest --hri-mark-fixed")
        shown = {e for o in ("regression", "error", "flaky") for e, _ in results.get(o, [])}
        for entry, note in self.notes.items():
            if entry not in shown:
                tr.write_line(f"changed     {entry}  ({note})")


def _count(n: int, outcome: str) -> str:
    return f"{n} {outcome}s" if outcome in ("regression", "error") and n != 1 else f"{n} {outcome}"
