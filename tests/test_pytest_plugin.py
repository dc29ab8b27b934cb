"""The pytest plugin: corpus entries replay as regression tests, judged by the spec's failure condition.

Each test builds a small project in pytester's folder: the toy spec and its plugin file under
``specs/``, and a corpus under ``tests/hri_failures/``. Entries are recorded with an untouched copy
of the toy plugins (scale 1, where every scenario below is a failure); the project's own copy is
then "fixed" (scale 0.7), so that goals on top of each other pass (objective 7) while a noisy
human still fails (objective 9.4): the failure condition is ``objective >= 8``.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from importlib.metadata import entry_points
from pathlib import Path

import hypothesis  # noqa: F401 - imported once here: its pytest plugin would import it in every inline run
import numpy as np
import pytest
from typer.testing import CliRunner

from hritest.cli import app
from hritest.corpus import dump_entry, load_entry
from hritest.domain import compile_spec
from hritest.evaluate import evaluate
from hritest.outcome_digest import outcome_digest
from hritest.records import scenario_digest
from hritest.rundir import digest
from hritest.spec import load_spec

pytest_plugins = ["pytester"]

FIXTURES = Path(__file__).parent / "fixtures"
QUIET = [0.0, 0.0, 0.0]
NOISY = [0.05, 0.05, 0.05]
# Scenarios (theta, in the order of toy.yaml): both goals on one spot, with a quiet or a noisy human.
PASSES_WHEN_FIXED = [[0.6, 0.05, 0.6, 0.05, *QUIET], [0.55, 0.0, 0.55, 0.0, *QUIET]]
FAILS_WHEN_FIXED = [[0.6, 0.05, 0.6, 0.05, *NOISY], [0.55, 0.0, 0.55, 0.0, *NOISY]]


@pytest.fixture(scope="module")
def recorder(tmp_path_factory):
    """The toy domain as it was when the failures were found (the plugins before the fix)."""
    folder = tmp_path_factory.mktemp("before")
    shutil.copy(FIXTURES / "toy_plugins.py", folder / "toy_plugins.py")
    shutil.copy(FIXTURES / "toy.yaml", folder / "toy.yaml")
    return compile_spec(load_spec(folder / "toy.yaml"))


class Project:
    """A pytester project with the (fixed) toy domain and a failure corpus."""

    def __init__(self, pytester: pytest.Pytester, recorder, *, corpus: str = "tests/hri_failures") -> None:
        self.pytester, self.recorder = pytester, recorder
        self.specs = pytester.path / "specs"
        self.specs.mkdir()
        plugins = (FIXTURES / "toy_plugins.py").read_text()
        assert plugins.count("scale: float = 1.0") == 1
        (self.specs / "toy_plugins.py").write_text(plugins.replace("scale: float = 1.0", "scale: float = 0.7"))
        shutil.copy(FIXTURES / "toy.yaml", self.specs / "toy.yaml")
        self.corpus = pytester.path / corpus

    def spec(self, name: str) -> Path:
        """A copy of the toy spec under another name (its own spec, for selection tests)."""
        path = self.specs / f"{name}.yaml"
        path.write_text((FIXTURES / "toy.yaml").read_text().replace("name: toy\n", f"name: {name}\n"))
        return path

    def record(
        self, theta: list[float], *, status: str, spec: Path | None = None, seed: int = 0, version: int = 2
    ) -> Path:
        """Writes the corpus entry of ``theta`` as the unfixed plugins evaluated it, as ``promote`` would
        (``version`` 1: as hritest wrote entries before outcome digests)."""
        spec = spec or self.specs / "toy.yaml"
        evaluation = evaluate(self.recorder, np.array(theta), seed=seed)
        assert evaluation.ok and evaluation.failure, "recorded entries are failures"
        spec_digest = digest(spec)
        scenario = scenario_digest(spec_digest, evaluation.theta_repaired, seed)
        labels = self.recorder.space.labels
        name = load_spec(spec).name
        path = self.corpus / name / f"{scenario[:12]}.yaml"
        path.parent.mkdir(parents=True, exist_ok=True)
        outcome = outcome_digest(self.recorder)
        added = {
            "outcome_digest": outcome.digest,
            "outcome_parts": dict(outcome.parts),
            "seconds": evaluation.seconds,
            "why": [str(c) for c in evaluation.fired],
        }
        path.write_text(
            dump_entry(
                {
                    "format": version,
                    "status": status,
                    "spec": str(Path("..", "..", "..", "specs", spec.name))
                    if self.corpus.parent.name == "tests"
                    else str(spec.resolve()),
                    "spec_name": name,
                    "spec_digest": spec_digest,
                    "failure_condition": "objective >= 8",
                    "seed": seed,
                    "objective": evaluation.objective,
                    "measures": {m.name: float(v) for m, v in zip(self.recorder.measures, evaluation.measures)},
                    "theta": dict(zip(labels, theta)),
                    "theta_repaired": dict(zip(labels, evaluation.theta_repaired.tolist())),
                    "metrics": evaluation.metrics,
                    "scenario_digest": scenario,
                    "versions": {"hritest": "0.1.0"},
                    "origin": {"run": "runs/toy", "evaluation": 7},
                    **(added if version == 2 else {}),
                }
            )
        )
        return path


@pytest.fixture
def project(pytester, recorder) -> Project:
    return Project(pytester, recorder)


def entry_id(path: Path) -> str:
    return f"{path.parent.name}/{path.stem}"


# --- registration ---------------------------------------------------------------------------------


def test_the_plugin_is_registered_and_imports_nothing_heavy():
    assert "hritest.pytest_plugin" in {ep.value for ep in entry_points(group="pytest11")}
    heavy = [
        "torch",
        "mujoco",
        "ribs",
        "ortools",
        "rerun",
        "numpy",
        "pydantic",
        "hritest.domain",
        "hritest.evaluate",
        "hritest.replay",
        "hritest.rundir",
        "hritest.search",
        "hritest.sim",
        "hritest.spec",
    ]
    code = f"import sys, hritest.pytest_plugin; print(sorted(m for m in {heavy!r} if m in sys.modules))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]", f"imported at plugin import time: {done.stdout}"


def test_no_corpus_means_no_header_and_no_section(pytester):
    pytester.makepyfile("def test_plain():\n    assert True\n")
    result = pytester.runpytest()
    result.assert_outcomes(passed=1)
    result.stdout.no_fnmatch_line("hritest: *")
    result.stdout.no_fnmatch_line("*= hritest =*")


# --- the four outcomes ----------------------------------------------------------------------------


def test_fixed_passing_regressed_still_failing_and_now_passing(project):
    fixed_ok = project.record(PASSES_WHEN_FIXED[0], status="fixed")
    regressed = project.record(FAILS_WHEN_FIXED[0], status="fixed")
    still = project.record(FAILS_WHEN_FIXED[1], status="open")
    now_ok = project.record(PASSES_WHEN_FIXED[1], status="open")

    result = project.pytester.runpytest("-rA")
    result.assert_outcomes(passed=1, failed=1, xfailed=1, xpassed=1)
    assert result.ret == pytest.ExitCode.TESTS_FAILED
    result.stdout.fnmatch_lines(
        [
            "hritest: failure corpus tests/hri_failures (4 entries)",
            "*= hritest =*",
            "corpus tests/hri_failures: 1 regression, 1 still failing, 1 now passing, 0 flaky, 1 passing",
            f"REGRESSION  {entry_id(regressed)}  (changed since recorded: task plugin source, robot plugin source, "
            "human plugin source; *)",
            "now passing (open failures that no longer fail):",
            f"  {entry_id(now_ok)}  (*)",
            f"mark them fixed: hritest promote --to tests/hri_failures --mark-fixed {entry_id(now_ok)}",
        ]
    )
    # The regression's report: what it was and what it is now, which clause fired, what changed since
    # it was recorded (the fix edited the plugins' file), and how to replay it.
    result.stdout.fnmatch_lines(
        [
            f"*hritest {entry_id(regressed)} was marked fixed but fails again: objective >= 8 (objective=9.425) "
            "(spec or plugins changed since this was recorded: task plugin source, robot plugin source, "
            "human plugin source)",
            "*recorded*now",
            "*objective*10*9.4*",
            "*goal_distance*",
            "  recorded: fails objective >= 8 (objective=10)",
            "  now:      fails objective >= 8 (objective=9.425)",
            f"replay it: hritest replay tests/hri_failures/toy/{regressed.name}",
        ]
    )
    result.stdout.fnmatch_lines(
        [
            f"XFAIL *{still.name}::toy::{still.stem} - hritest open failure still fails: "
            "objective >= 8 (objective=9.425)*"
        ]
    )
    result.stdout.fnmatch_lines(
        [f"XPASS *{now_ok.name}::toy::{now_ok.stem}*no longer fails*; it failed: objective >= 8 (objective=10)"]
    )
    # The now-passing entry's report section says how to mark it fixed; nothing was changed.
    result.stdout.fnmatch_lines(["*hritest*", f"open failure {entry_id(now_ok)} no longer fails*"])
    assert load_entry(now_ok).status == "open" and load_entry(fixed_ok).status == "fixed"


def test_without_regressions_the_session_passes(project):
    project.record(PASSES_WHEN_FIXED[0], status="fixed")
    project.record(FAILS_WHEN_FIXED[0], status="open")
    result = project.pytester.runpytest()
    result.assert_outcomes(passed=1, xfailed=1)
    assert result.ret == pytest.ExitCode.OK


def test_mark_fixed_option_flips_now_passing_entries(project):
    now_ok = project.record(PASSES_WHEN_FIXED[0], status="open")
    still = project.record(FAILS_WHEN_FIXED[0], status="open")
    before = now_ok.read_text()

    result = project.pytester.runpytest("--hri-mark-fixed")
    result.assert_outcomes(xfailed=1, xpassed=1)
    result.stdout.fnmatch_lines(["now passing (open failures that no longer fail, marked fixed):"])
    assert load_entry(now_ok).status == "fixed" and load_entry(still).status == "open"
    changed = [(a, b) for a, b in zip(before.splitlines(), now_ok.read_text().splitlines()) if a != b]
    assert changed == [("status: open", "status: fixed")]  # a one-line diff

    project.pytester.runpytest().assert_outcomes(passed=1, xfailed=1)


def test_fixed_entries_that_fail_are_regressions_whatever_changed_in_the_spec(project):
    project.recorder = compile_spec(load_spec(project.specs / "toy.yaml"))  # recorded with today's plugins
    entries = [project.record(theta, status="fixed") for theta in FAILS_WHEN_FIXED]
    spec = project.specs / "toy.yaml"
    # a comment and a search setting decide no outcome: the entries replay, with nothing to note
    spec.write_text("# a comment\n" + spec.read_text().replace("budget: 500", "budget: 50"))
    result = project.pytester.runpytest()
    result.assert_outcomes(failed=2)
    assert result.ret == pytest.ExitCode.TESTS_FAILED
    result.stdout.no_fnmatch_line("*changed since*")
    # a changed failure condition is shown beside the verdict, and a fixed entry that fails still fails
    spec.write_text(spec.read_text().replace("failure: objective >= 8", "failure: objective >= 9"))
    result = project.pytester.runpytest()
    result.assert_outcomes(failed=2)
    result.stdout.fnmatch_lines(
        [
            f"*{entry_id(entries[0])} was marked fixed but fails again: objective >= 9 (objective=9.425) (spec or "
            "plugins changed since this was recorded: failure condition)",
        ]
    )


def test_an_entry_of_format_1_replays_and_says_when_its_spec_file_changed(project):
    entry = project.record(FAILS_WHEN_FIXED[0], status="fixed", version=1)
    assert "outcome_digest" not in entry.read_text() and load_entry(entry).format == 1
    project.pytester.runpytest().assert_outcomes(failed=1)
    spec = project.specs / "toy.yaml"
    spec.write_text(spec.read_text() + "# edited\n")
    result = project.pytester.runpytest()
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*fails again*changed since this was recorded: the spec file (recorded before*"])


def test_an_entry_whose_spec_is_gone_or_outside_the_project_is_an_error(project, tmp_path):
    entry = project.record(FAILS_WHEN_FIXED[0], status="open")
    gone = project.corpus / "toy" / entry.name
    text = entry.read_text()
    gone.write_text(text.replace("spec: ../../../specs/toy.yaml", "spec: ../../../specs/gone.yaml"))
    result = project.pytester.runpytest()
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines([f"hritest {entry_id(entry)} cannot be replayed: its spec * no longer exists*"])

    outside = tmp_path / "elsewhere"
    outside.mkdir()
    shutil.copy(project.specs / "toy.yaml", outside / "toy.yaml")
    shutil.copy(project.specs / "toy_plugins.py", outside / "toy_plugins.py")
    entry.write_text(text.replace("spec: ../../../specs/toy.yaml", f"spec: {outside / 'toy.yaml'}"))
    result = project.pytester.runpytest()
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*field 'spec' names *elsewhere/toy.yaml, outside the project*--hri-allow-outside*"])
    project.pytester.runpytest("--hri-allow-outside").assert_outcomes(xfailed=1)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (("  g0x: 0.6\n", "  g0x: 0.52\n"), "field 'theta' does not repair to the stored field 'theta_repaired'*g0x*"),
        (("seed: 0\n", "seed: 1\n"), "field 'scenario_digest': does not match*"),
    ],
)
def test_a_fixed_entry_edited_to_pass_is_an_error_naming_the_field(project, edit, message):
    project.recorder = compile_spec(load_spec(project.specs / "toy.yaml"))
    path = project.record(FAILS_WHEN_FIXED[0], status="fixed")
    old, new = edit
    assert old in path.read_text()  # the first is theta's (theta_repaired follows it)
    path.write_text(path.read_text().replace(old, new, 1))
    result = project.pytester.runpytest()
    assert result.ret != pytest.ExitCode.OK
    result.stdout.fnmatch_lines([f"*{message}"])


def test_a_misplaced_entry_file_is_an_error(project):
    entry = project.record(FAILS_WHEN_FIXED[0], status="open")
    (project.corpus / "loose.yaml").write_text(entry.read_text())
    (project.corpus / "toy" / "other.yml").write_text(entry.read_text())
    (project.corpus / "toy" / "deeper").mkdir()
    (project.corpus / "toy" / "deeper" / entry.name).write_text(entry.read_text())
    result = project.pytester.runpytest()
    assert result.ret == pytest.ExitCode.INTERRUPTED
    result.stdout.fnmatch_lines(["*corpus entries live in a folder per spec*"])
    result.stdout.fnmatch_lines(["*rename it to other.yaml*"])
    result.stdout.fnmatch_lines(["*one folder deep*"])


def test_a_missing_hri_corpus_folder_is_a_usage_error(project):
    result = project.pytester.runpytest("--hri-corpus", "no/such/folder")
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines(["*--hri-corpus no/such/folder: * is not a folder*"])


@pytest.mark.parametrize(
    ("fault", "args", "message"),
    [
        ("hang", ["--hri-timeout", "2"], "did not finish within 2 s*"),
        ("exit", [], "the replay process died (exit status 3)*"),
    ],
)
def test_a_plugin_that_hangs_or_kills_its_process_fails_the_entry(project, fault, args, message):
    hung = project.record(FAILS_WHEN_FIXED[0], status="fixed")  # noise[0] = 0.05 > fault_above
    fine = project.record(PASSES_WHEN_FIXED[1], status="fixed")
    plugins = project.specs / "toy_plugins.py"
    plugins.write_text(plugins.read_text().replace('= "none"\n', f'= "{fault}"\n'))
    result = project.pytester.runpytest(*args)
    result.assert_outcomes(failed=1, passed=1)  # the worker is replaced, and the next entry replays
    assert result.ret == pytest.ExitCode.TESTS_FAILED
    result.stdout.fnmatch_lines([f"hritest {entry_id(hung)} cannot be replayed: {message}"])
    assert load_entry(fine).status == "fixed"


def test_a_spec_that_compiles_past_the_compile_timeout_fails_its_entries_naming_the_option(project):
    entry = project.record(FAILS_WHEN_FIXED[0], status="open")
    plugins = project.specs / "toy_plugins.py"
    plugins.write_text(plugins.read_text() + "\ntime.sleep(60)  # a plugin module that imports slowly\n")
    result = project.pytester.runpytest("--hri-compile-timeout", "2")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(
        [
            f"hritest {entry_id(entry)} cannot be replayed: compiling its spec: did not finish within 2 s*"
            "(raise the limit with --hri-compile-timeout)*"
        ]
    )
    usage = project.pytester.runpytest("--hri-compile-timeout", "0")
    assert usage.ret == pytest.ExitCode.USAGE_ERROR
    usage.stderr.fnmatch_lines(["*--hri-compile-timeout must be a positive number of seconds, got 0.0*"])


def test_replays_with_several_seeds_report_an_entry_that_fails_sometimes_as_flaky(project):
    plugins = project.specs / "toy_plugins.py"
    text = plugins.read_text()
    assert text.count("        distance = float(np.linalg.norm(g0 - g1))\n") == 1
    plugins.write_text(  # a stochastic task: the noisy scenario (objective 9.4) fails with some seeds only
        text.replace(
            "        distance = float(np.linalg.norm(g0 - g1))\n",
            "        distance = float(np.linalg.norm(g0 - g1)) + float(rng.uniform(0, 0.05))\n",
        )
    )
    open_entry = project.record(FAILS_WHEN_FIXED[0], status="open")
    fixed = project.record(FAILS_WHEN_FIXED[1], status="fixed")
    result = project.pytester.runpytest("--hri-replays", "8", "-rxX")
    result.assert_outcomes(xfailed=1, failed=1)
    result.stdout.fnmatch_lines(
        [
            f"XFAIL *{open_entry.stem} - hritest open failure (flaky: fails *% of its replays) still fails with "
            "* of 8 seeds: objective >= 8 *; passes with seed *",
        ]
    )
    result.stdout.fnmatch_lines([f"FLAKY       {entry_id(open_entry)}  (fails *% of its replays; *"])
    result.stdout.fnmatch_lines(
        [
            f"*{entry_id(fixed)} was marked fixed but fails again with * of 8 seeds*",
            "  now:      fails objective >= 8 * (seed *; recorded with seed 0)",
        ]
    )
    result.stdout.fnmatch_lines(["corpus tests/hri_failures: 1 regression, 0 still failing, 0 now passing, 1 flaky"])


def test_a_stored_failure_that_now_crashes_fails_with_the_plugins_message(project):
    entry = project.record(FAILS_WHEN_FIXED[0], status="open")  # noise[0] = 0.05 > fault_above
    plugins = project.specs / "toy_plugins.py"
    plugins.write_text(plugins.read_text().replace('= "none"\n', '= "raise"\n'))
    result = project.pytester.runpytest()
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(
        [
            f"hritest {entry_id(entry)} cannot be replayed: no longer evaluates: status plugin_error (seed 0)",
            "task plugin ToyTask raised RuntimeError: toy plugin exploded",
            "corpus tests/hri_failures: 0 regressions, 0 still failing, 0 now passing, 0 flaky, 1 error",
            f"ERROR       {entry_id(entry)}  (*)",
        ]
    )


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ("seed: 0", "seed: zero", "seed"),
        ("status: open", "status: maybe", "status"),
        ("seed: 0\n", "", "seed"),
        ("  g0x: 0.6\n", "  g0x: [0.6]\n", "theta.g0x"),
        ("outcome_parts:", "outcome_partz:", "outcome_parts"),  # format 2 needs its outcome digest
        ("why:\n- ", "why: ", "why"),
        ("scenario_digest: ", "scenario_digest: 0", "scenario_digest"),
    ],
)
def test_a_malformed_entry_is_a_collection_error_naming_file_and_field(project, old, new, field):
    path = project.record(FAILS_WHEN_FIXED[0], status="open")
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))
    result = project.pytester.runpytest()
    assert result.ret == pytest.ExitCode.INTERRUPTED
    result.stdout.fnmatch_lines(
        [f"*ERROR collecting tests/hri_failures/toy/{path.name}*", f"hritest corpus: {path}: field '{field}'*"]
    )


def test_yaml_that_does_not_parse_is_a_collection_error(project):
    path = project.record(FAILS_WHEN_FIXED[0], status="open")
    path.write_text(path.read_text() + "seed: [unclosed\n")
    result = project.pytester.runpytest()
    assert result.ret == pytest.ExitCode.INTERRUPTED
    result.stdout.fnmatch_lines([f"hritest corpus: {path}:*: is not valid YAML*"])


# --- selection --------------------------------------------------------------------------------------


def test_entries_are_named_after_spec_and_id_and_select_with_k_and_hri_spec(project):
    toy = project.record(FAILS_WHEN_FIXED[0], status="open")
    collab = project.record(FAILS_WHEN_FIXED[0], status="open", spec=project.spec("collabtoy"))

    result = project.pytester.runpytest("--collect-only", "-q")
    result.stdout.fnmatch_lines(
        [
            f"tests/hri_failures/collabtoy/{collab.name}::collabtoy::{collab.stem}",
            f"tests/hri_failures/toy/{toy.name}::toy::{toy.stem}",
        ]
    )
    project.pytester.runpytest("-k", "collab").assert_outcomes(xfailed=1, deselected=1)
    project.pytester.runpytest("--hri-spec", "toy").assert_outcomes(xfailed=1, deselected=1)
    project.pytester.runpytest("--hri-spec", "specs/collabtoy.yaml").assert_outcomes(xfailed=1, deselected=1)
    project.pytester.runpytest("-m", "hri").assert_outcomes(xfailed=2)
    # a node id selects exactly one entry
    project.pytester.runpytest(f"tests/hri_failures/toy/{toy.name}::toy::{toy.stem}").assert_outcomes(xfailed=1)


def test_a_corpus_outside_the_test_paths_is_found_from_pyproject(pytester, recorder):
    project = Project(pytester, recorder, corpus="regressions/hri")
    pytester.makepyprojecttoml(
        '[tool.pytest.ini_options]\ntestpaths = ["tests"]\n\n[tool.hritest]\ncorpus = "regressions/hri"\n'
    )
    pytester.mkdir("tests")
    pytester.path.joinpath("tests", "test_unit.py").write_text("def test_unit():\n    pass\n")
    project.record(FAILS_WHEN_FIXED[0], status="open")
    result = pytester.runpytest()
    result.assert_outcomes(passed=1, xfailed=1)
    result.stdout.fnmatch_lines(["hritest: failure corpus regressions/hri (1 entry)"])
    # and with --hri-corpus given, even beside explicit test paths
    pytester.runpytest("tests/test_unit.py", "--hri-corpus", "regressions/hri").assert_outcomes(passed=1, xfailed=1)


# --- the fixture ----------------------------------------------------------------------------------


def test_hri_scenario_fixture_simulates_a_scenario(project):
    project.pytester.makepyfile(
        test_mine="""
        def test_goals_apart(hri_scenario):
            evaluation, rollout = hri_scenario("specs/toy.yaml", [0.52, -0.08, 0.68, 0.18, 0, 0, 0])
            assert evaluation.status == "ok" and not evaluation.failure
            assert rollout.metrics["min_goal_distance"] > 0.05

        def test_goals_together_by_label(hri_scenario):
            theta = {"g0x": 0.6, "g0y": 0.05, "g1x": 0.6, "g1y": 0.05,
                     "noise[0]": 0.05, "noise[1]": 0.05, "noise[2]": 0.05}
            evaluation, rollout = hri_scenario("specs/toy.yaml", theta, seed=3)
            assert evaluation.failure and evaluation.seed == 3
            assert rollout.metrics["min_goal_distance"] < 0.05

        def test_wrong_length(hri_scenario):
            hri_scenario("specs/toy.yaml", [0.5])
    """
    )
    result = project.pytester.runpytest("-m", "hri")
    result.assert_outcomes(passed=2, failed=1)
    result.stdout.fnmatch_lines(["*ValueError: hri_scenario: specs/toy.yaml needs 7 theta values*got 1"])


# --- the optional search --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def searched_once(tmp_path_factory) -> None:
    """Runs one small search in this process first: a search imports numba lazily, and numba cannot be
    imported a second time after an inline pytest run drops what it imported from sys.modules."""
    from hritest import search as qd

    folder = tmp_path_factory.mktemp("warm")
    shutil.copy(FIXTURES / "toy_plugins.py", folder / "toy_plugins.py")
    shutil.copy(FIXTURES / "toy.yaml", folder / "toy.yaml")
    qd.start(
        spec_file=folder / "toy.yaml",
        out=folder / "run",
        algorithm="random",
        budget=20,
        seed=0,
        backend=qd.Backend(workers=1),
    )


def test_search_budget_fails_on_failures_the_corpus_does_not_hold(project, searched_once):
    shutil.copy(FIXTURES / "toy_plugins.py", project.specs / "toy_plugins.py")  # unfixed: failures are common
    project.record(FAILS_WHEN_FIXED[0], status="open")
    result = project.pytester.runpytest("--hri-search-budget", "40")
    result.assert_outcomes(xfailed=1, failed=1)
    result.stdout.fnmatch_lines(
        [
            "*a Random search of 40 evaluations found * failure(s) of toy that the corpus does not hold:",
            "keep them: hritest promote .pytest_cache/d/hritest-search/toy --to tests/hri_failures",
            "corpus tests/hri_failures: 0 regressions, 1 still failing, 0 now passing, 0 flaky, "
            "1 search with new failures",
            "NEW         toy/search  (failures the corpus does not hold; tests/hri_failures/toy::search)",
        ]
    )
    run = project.pytester.path / ".pytest_cache" / "d" / "hritest-search" / "toy"
    promoted = CliRunner().invoke(app, ["promote", str(run), "--to", str(project.corpus)])
    assert promoted.exit_code == 0, promoted.output
    # the same search (the spec's seed) now finds nothing new; the promoted failures replay as xfail
    result = project.pytester.runpytest("--hri-search-budget", "40")
    assert result.ret == pytest.ExitCode.OK
    assert result.parseoutcomes()["passed"] == 1  # the search
