"""``hritest new``: the domain it writes works as written, through every step of the workflow."""

from __future__ import annotations

import json
import py_compile
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from hritest.cli import app

runner = CliRunner()


def invoke(*args: str | Path):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def domain(tmp_path_factory) -> Path:
    """``hritest new hallway``, as written; returns the spec's path."""
    folder = tmp_path_factory.mktemp("new")
    result = invoke("new", "hallway", "--dir", folder)
    assert result.exit_code == 0, result.output
    assert f"wrote {folder / 'hallway.yaml'} and {folder / 'hallway_plugins.py'}" in result.output
    return folder / "hallway.yaml"


def search(spec: Path, out: Path, algorithm: str, budget: int) -> list[dict]:
    """A search through the command line; returns its evaluations."""
    extra = ["--inner-iterations", "3"] if algorithm in ("sas", "dsas") else []
    result = invoke(
        "search",
        spec,
        "--algorithm",
        algorithm,
        "--budget",
        budget,
        "--seed",
        0,
        "--workers",
        2,
        "--quiet",
        "--out",
        out,
        *extra,
    )
    assert result.exit_code in (0, 1) and isinstance(result.exception, SystemExit | None), result.output
    return [json.loads(line) for line in (out / "evaluations.jsonl").read_text().splitlines()]


def test_the_new_domain_compiles_and_passes_check(domain):
    py_compile.compile(str(domain.with_name("hallway_plugins.py")), doraise=True)
    assert invoke("validate", domain).exit_code == 0
    result = invoke("check", domain)
    assert result.exit_code == 0, result.output
    assert "same seed, same outcome" in result.output and "ready to search" in result.output


@pytest.mark.parametrize("algorithm", ["random", "map_elites", "cma_mae", "sas", "dsas"])
def test_the_new_domain_searches_with_every_algorithm(domain, tmp_path, algorithm):
    spec = domain
    if algorithm in ("sas", "dsas"):  # fewer initial scenarios, so the surrogate trains within the budget
        spec = domain.with_name(f"hallway_{algorithm}.yaml")
        text = domain.read_text()
        assert "initial_evaluations: 100" in text
        spec.write_text(text.replace("initial_evaluations: 100", "initial_evaluations: 20"))
    records = search(spec, tmp_path / "run", algorithm, 40)
    assert sorted(r["index"] for r in records) == list(range(40))
    assert {r["status"] for r in records} == {"ok"}, [r["message"] for r in records if r["status"] != "ok"][:3]
    if algorithm in ("sas", "dsas"):
        assert json.loads((tmp_path / "run" / "surrogate.json").read_text())["held_out"] > 0


def test_a_search_of_the_new_domain_reports_replays_and_promotes(domain, tmp_path):
    run = tmp_path / "run"
    search(domain, run, "cma_mae", 40)
    failures = yaml.safe_load((run / "failures.yaml").read_text())["failures"]
    assert failures, "the tiny search found no failure to replay and promote"

    result = invoke("report", run, "--recordings", 0)
    assert result.exit_code == 0, result.output
    assert (run / "report" / "index.html").is_file()

    result = invoke("replay", run, "--failure", failures[0]["id"], "--out", tmp_path / "failure.rrd")
    assert result.exit_code == 0, result.output
    assert "replay matches" in result.output and (tmp_path / "failure.rrd").is_file()

    corpus = tmp_path / "corpus"
    result = invoke("promote", run, "--top", 1, "--to", corpus)
    assert result.exit_code == 0, result.output
    [entry] = (corpus / "hallway").glob("*.yaml")
    data = yaml.safe_load(entry.read_text())
    assert data["status"] == "open" and (entry.parent / data["spec"]).resolve() == domain.resolve()


def test_new_never_overwrites(tmp_path):
    (tmp_path / "mine_plugins.py").write_text("# my work\n")
    result = invoke("new", "mine", "--dir", tmp_path)
    assert result.exit_code == 2
    assert "exists already" in result.output and "never overwrites" in result.output
    assert (tmp_path / "mine_plugins.py").read_text() == "# my work\n"
    assert not (tmp_path / "mine.yaml").exists()  # all or nothing


@pytest.mark.parametrize(
    ("name", "suggestion"), [("my-domain", "my_domain"), ("2arms", "domain_2arms"), ("_x", "x"), ("é", "my_domain")]
)
def test_a_bad_name_exits_2_with_one_to_use(tmp_path, name, suggestion):
    result = invoke("new", name, "--dir", tmp_path)
    assert result.exit_code == 2
    assert "starting with a letter" in result.output and f"e.g. {suggestion}" in result.output
    assert not list(tmp_path.iterdir())
