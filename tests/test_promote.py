"""hritest promote: a run's failures become corpus files, idempotently; --mark-fixed; bad input exits 2."""

from __future__ import annotations

import shutil
from pathlib import Path

import hypothesis  # noqa: F401 - imported once here: its pytest plugin would import it in every inline run
import pytest
import yaml
from typer.testing import CliRunner

from hritest import search as qd
from hritest.cli import app
from hritest.corpus import default_corpus, load_entry
from hritest.rundir import RunDirectory, digest

pytest_plugins = ["pytester"]

FIXTURES = Path(__file__).parent / "fixtures"
runner = CliRunner()


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A finished toy search with failures (its spec and plugins beside it, under project/specs)."""
    folder = tmp_path_factory.mktemp("project")
    (folder / "specs").mkdir()
    shutil.copy(FIXTURES / "toy_plugins.py", folder / "specs" / "toy_plugins.py")
    shutil.copy(FIXTURES / "toy.yaml", folder / "specs" / "toy.yaml")
    qd.start(
        spec_file=folder / "specs" / "toy.yaml",
        out=folder / "run",
        algorithm="random",
        budget=120,
        seed=4,
        backend=qd.Backend(workers=1),
    )
    return folder / "run"


def failures(run: Path) -> list[dict]:
    found = yaml.safe_load((run / "failures.yaml").read_text())["failures"]
    assert len(found) >= 3, "the toy search should find a few failures"
    return found


def promote(*args: object) -> object:
    return runner.invoke(app, ["promote", *map(str, args)])


def test_promote_writes_one_readable_file_per_failure_and_is_idempotent(run, tmp_path):
    corpus = tmp_path / "corpus"
    result = promote(run, "--to", corpus)
    assert result.exit_code == 0, result.output
    stored = failures(run)
    files = sorted(corpus.glob("toy/*.yaml"))
    assert len(files) == len(stored)
    assert f"{len(stored)} added, 0 already in the corpus" in result.output

    texts = {f: f.read_text() for f in files}
    again = promote(run, "--to", corpus)
    assert again.exit_code == 0, again.output
    assert f"0 added, {len(stored)} already in the corpus" in again.output
    assert {f: f.read_text() for f in sorted(corpus.glob("toy/*.yaml"))} == texts

    # The worst failure's entry holds what the run recorded.
    records = {r.index: r for r in RunDirectory.open(run).evaluations()}
    worst = stored[0]
    entries = {e.origin["evaluation"]: e for e in map(load_entry, files)}
    entry = entries[worst["id"]]
    record = records[worst["id"]]
    meta = RunDirectory.open(run).meta
    assert entry.status == "open" and entry.spec_name == "toy"
    assert entry.spec_path == Path(meta["spec_file"]) and entry.spec_digest == meta["spec_digest"]
    assert list(entry.theta.values()) == list(record.theta)
    assert list(entry.theta_repaired.values()) == list(record.theta_repaired) == list(worst["theta"].values())
    assert list(entry.theta) == list(worst["theta"])  # labelled as 'hritest show' lists them
    assert entry.objective == record.objective and entry.measures == worst["measures"]
    assert entry.metrics == record.metrics and entry.seed == record.seed
    assert entry.versions["hritest"] == meta["versions"]["hritest"]
    assert entry.versions["mujoco"] == meta["versions"]["mujoco"]
    assert entry.origin["run"] == str(run.resolve())
    assert entry.path.name == f"{entry.scenario_digest[:12]}.yaml"
    assert not entry.spec.startswith("/")  # relative to the corpus file, so the repository can move


def test_top_takes_the_worst_and_mark_fixed_flips_status(run, tmp_path):
    corpus = tmp_path / "corpus"
    result = promote(run, "--to", corpus, "--top", 2)
    assert result.exit_code == 0, result.output
    entries = [load_entry(f) for f in sorted(corpus.glob("toy/*.yaml"))]
    assert sorted(e.origin["evaluation"] for e in entries) == sorted(f["id"] for f in failures(run)[:2])

    first, second = entries
    before = first.path.read_text()
    result = promote("--to", corpus, "--mark-fixed", first.id, "--mark-fixed", second.path.name)
    assert result.exit_code == 0, result.output
    assert "open -> fixed" in result.output
    assert [load_entry(e.path).status for e in entries] == ["fixed", "fixed"]
    changed = [(a, b) for a, b in zip(before.splitlines(), first.path.read_text().splitlines()) if a != b]
    assert changed == [("status: open", "status: fixed")]

    # marking again, and promoting the same failures again, keeps them fixed
    assert "was already fixed" in promote("--to", corpus, "--mark-fixed", f"toy/{first.id}").output
    assert promote(run, "--to", corpus, "--top", 2).exit_code == 0
    assert [load_entry(e.path).status for e in entries] == ["fixed", "fixed"]


def test_promoting_again_upgrades_a_format_1_entry_and_keeps_its_status(run, tmp_path):
    corpus = tmp_path / "corpus"
    assert promote(run, "--to", corpus, "--top", 1).exit_code == 0
    [path] = corpus.glob("toy/*.yaml")
    data = yaml.safe_load(path.read_text())
    for key in ("outcome_digest", "outcome_parts", "seconds", "why"):
        del data[key]
    path.write_text(yaml.safe_dump({**data, "format": 1, "status": "fixed"}))
    assert load_entry(path).format == 1

    result = promote(run, "--to", corpus, "--top", 1)
    assert result.exit_code == 0, result.output
    assert "upgraded" in result.output
    entry = load_entry(path)
    assert (entry.format, entry.status) == (2, "fixed") and entry.outcome_parts and entry.why


def test_the_default_corpus_comes_from_the_nearest_pyproject(run, tmp_path, monkeypatch):
    (tmp_path / "pyproject.toml").write_text('[project]\nname = "mine"\n\n[tool.hritest]\ncorpus = "hri/corpus"\n')
    (tmp_path / "src").mkdir()
    monkeypatch.chdir(tmp_path / "src")
    assert default_corpus(Path.cwd()) == tmp_path / "hri" / "corpus"
    result = promote(run, "--top", 1)
    assert result.exit_code == 0, result.output
    assert len(list((tmp_path / "hri" / "corpus" / "toy").glob("*.yaml"))) == 1

    (tmp_path / "pyproject.toml").write_text('[project]\nname = "mine"\n')
    assert default_corpus(Path.cwd()) == tmp_path / "tests" / "hri_failures"


def test_promoted_failures_replay_under_pytest_as_open_failures(run, pytester):
    corpus = pytester.path / "tests" / "hri_failures"
    assert promote(run, "--to", corpus, "--top", 3).exit_code == 0
    entry = load_entry(next(corpus.glob("toy/*.yaml")))
    assert entry.format == 2 and len(entry.outcome_digest) == 64 and entry.seconds is not None
    assert {"task plugin source", "failure condition", "scenario space"} <= set(entry.outcome_parts)
    assert entry.why and entry.why[0].startswith("objective >= 8 (objective=")
    # the run's spec lies outside pytester's project: its plugins run only when that is allowed
    result = pytester.runpytest("--hri-allow-outside")
    result.assert_outcomes(xfailed=3)
    result.stdout.fnmatch_lines(["corpus tests/hri_failures: 0 regressions, 3 still failing, 0 now passing, 0 flaky"])
    pytester.runpytest().assert_outcomes(failed=3)


def test_fixed_entries_that_still_fail_fail_pytest_after_a_comment_and_a_search_setting(pytester):
    specs = pytester.path / "specs"
    specs.mkdir()
    shutil.copy(FIXTURES / "toy_plugins.py", specs / "toy_plugins.py")
    shutil.copy(FIXTURES / "toy.yaml", specs / "toy.yaml")
    run = pytester.path / "runs" / "toy"
    qd.start(
        spec_file=specs / "toy.yaml", out=run, algorithm="random", budget=60, seed=4, backend=qd.Backend(workers=1)
    )
    corpus = pytester.path / "tests" / "hri_failures"
    assert promote(run, "--to", corpus, "--top", 3).exit_code == 0
    ids = [f.stem for f in corpus.glob("toy/*.yaml")]
    assert len(ids) == 3
    assert promote("--to", corpus, *[a for i in ids for a in ("--mark-fixed", i)]).exit_code == 0
    spec = specs / "toy.yaml"
    spec.write_text("# a comment that decides nothing\n" + spec.read_text().replace("budget: 500", "budget: 5"))
    result = pytester.runpytest()
    result.assert_outcomes(failed=3)
    assert result.ret == pytest.ExitCode.TESTS_FAILED
    result.stdout.fnmatch_lines(["corpus tests/hri_failures: 3 regressions, *"])
    result.stdout.no_fnmatch_line("*changed since*")


def test_top_keeps_the_worst_failure_of_every_clause_that_fired(tmp_path):
    shutil.copy(FIXTURES / "toy_plugins.py", tmp_path / "toy_plugins.py")
    spec = tmp_path / "toy.yaml"
    # far-apart goals make the second clause fire with a low objective, never among the highest
    spec.write_text(
        (FIXTURES / "toy.yaml")
        .read_text()
        .replace("failure: objective >= 8", "failure: objective >= 9.5 or goal_distance >= 0.25")
    )
    qd.start(
        spec_file=spec, out=tmp_path / "run", algorithm="random", budget=200, seed=1, backend=qd.Backend(workers=1)
    )
    records = {r.index: r for r in RunDirectory.open(tmp_path / "run").evaluations()}
    reported = [records[f["id"]] for f in failures(tmp_path / "run")]
    fired = {c.text for r in reported for c in r.fired}
    assert fired == {"objective >= 9.5", "goal_distance >= 0.25"}
    by_objective = sorted(reported, key=lambda r: -r.objective)[:2]
    assert all(c.text == "objective >= 9.5" for r in by_objective for c in r.fired)  # what --top used to keep

    assert promote(tmp_path / "run", "--to", tmp_path / "corpus", "--top", 2).exit_code == 0
    kept = [load_entry(f) for f in (tmp_path / "corpus").glob("toy/*.yaml")]
    assert len(kept) == 2
    assert {w.split(" (")[0] for e in kept for w in e.why} == fired


@pytest.mark.parametrize(
    "case",
    ["not-a-run", "missing", "unwritable", "unknown-id", "nothing", "top-0", "spec-changed", "mark-fixed-as-run"],
)
def test_bad_input_exits_2_and_writes_nothing(run, tmp_path, case):
    corpus = tmp_path / "corpus"
    plain = tmp_path / "plain"
    plain.mkdir()
    if case == "not-a-run":
        args = [plain, "--to", corpus]
    elif case == "missing":
        args = [tmp_path / "nope", "--to", corpus]
    elif case == "unwritable":
        blocker = tmp_path / "file"
        blocker.write_text("a file, not a folder")
        args = [run, "--to", blocker / "corpus"]
    elif case == "unknown-id":
        assert promote(run, "--to", corpus, "--top", 1).exit_code == 0
        before = {f: f.read_text() for f in corpus.rglob("*.yaml")}
        result = promote("--to", corpus, "--mark-fixed", next(iter(before)).stem, "--mark-fixed", "0123456789ab")
        assert result.exit_code == 2, result.output
        assert "no corpus entry '0123456789ab'" in result.output and "its entries are: toy/" in result.output
        assert {f: f.read_text() for f in corpus.rglob("*.yaml")} == before  # the known one was not changed
        return
    elif case == "nothing":
        args = []
    elif case == "top-0":
        args = [run, "--top", 0, "--to", corpus]
    elif case == "spec-changed":
        changed = tmp_path / "run"
        shutil.copytree(run, changed)
        spec = tmp_path / "toy.yaml"
        spec.write_text((FIXTURES / "toy.yaml").read_text() + "# edited\n")
        meta = (changed / "run.json").read_text().replace(RunDirectory.open(run).meta["spec_file"], str(spec))
        (changed / "run.json").write_text(meta)
        assert digest(spec) != RunDirectory.open(changed).meta["spec_digest"]
        args = [changed, "--to", corpus]
    else:  # several ids after one --mark-fixed: the second is taken for RUN
        args = ["--to", corpus, "--mark-fixed", "abc", "def"]
    result = promote(*args)
    assert result.exit_code == 2, result.output
    assert not corpus.exists() or not any(corpus.rglob("*.yaml"))
