"""hritest replay: stored failures re-simulate to their stored outcome; tampering and bad input are caught."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from hritest import search as qd
from hritest.cli import app
from hritest.recording import recorded_entities
from hritest.replay import TOLERANCE, UnknownFailureError, compare, replay_failure

FIXTURES = Path(__file__).parent / "fixtures"
SPECS = Path(__file__).parent.parent / "specs"
runner = CliRunner()


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("toy")
    shutil.copy(FIXTURES / "toy_plugins.py", folder / "toy_plugins.py")
    shutil.copy(FIXTURES / "toy.yaml", folder / "toy.yaml")
    qd.start(
        spec_file=folder / "toy.yaml",
        out=folder / "run",
        algorithm="random",
        budget=120,
        seed=4,
        backend=qd.Backend(workers=1),
    )
    return folder / "run"


def first_failure(run: Path) -> int:
    failures = yaml.safe_load((run / "failures.yaml").read_text())["failures"]
    assert failures, "the toy search should find failures"
    return failures[0]["id"]


def test_a_stored_failure_replays_to_its_stored_outcome(run):
    fid = first_failure(run)
    result = runner.invoke(app, ["replay", str(run), "--failure", str(fid)])
    assert result.exit_code == 0, result.output
    assert "replay matches" in result.output
    assert "objective and measures within 1e-06 absolute" in result.output
    assert f"evaluation {fid} as stored in evaluations.jsonl" in result.output
    assert "stored:   fails objective >= 8 (objective=" in result.output  # the clause that fired, then and now
    assert "replayed: fails objective >= 8 (objective=" in result.output
    path = run / "recordings" / f"{fid}.rrd"
    assert path.is_file()
    assert "world/robot/path" in recorded_entities(path)  # the toy task's one trajectory

    replayed = replay_failure(run, fid)
    assert replayed.matches and [c.name for c in replayed.checks] == [
        "status",
        "failure",
        "objective",
        "goal_distance",
        "variation",
    ]


def test_a_tampered_stored_objective_is_a_finding(run, tmp_path):
    fid = first_failure(run)
    tampered = tmp_path / "run"
    shutil.copytree(run, tampered)
    lines = (tampered / "evaluations.jsonl").read_text().splitlines()
    for i, line in enumerate(lines):
        record = json.loads(line)
        if record["index"] == fid:
            record["objective"] += 10 * TOLERANCE
            lines[i] = json.dumps(record)
    (tampered / "evaluations.jsonl").write_text("\n".join(lines) + "\n")
    result = runner.invoke(app, ["replay", str(tampered), "--failure", str(fid), "--out", str(tmp_path / "t.rrd")])
    assert result.exit_code == 1, result.output
    assert "DIFFERS" in result.output and "replay does NOT match" in result.output
    assert (tmp_path / "t.rrd").is_file()  # the recording is still written, to look at


def test_a_corpus_entry_replays_against_what_it_recorded(run, tmp_path, monkeypatch):
    corpus = tmp_path / "corpus"
    assert runner.invoke(app, ["promote", str(run), "--top", "1", "--to", str(corpus)]).exit_code == 0
    [entry] = corpus.glob("toy/*.yaml")
    monkeypatch.chdir(tmp_path)
    result = runner.invoke(app, ["replay", str(entry)])
    assert result.exit_code == 0, result.output
    assert f"corpus entry toy/{entry.stem} as recorded" in result.output and "replay matches" in result.output
    assert "stored:   fails objective >= 8 (objective=" in result.output
    assert (tmp_path / "recordings" / f"{entry.stem}.rrd").is_file()

    text = entry.read_text()
    objective = next(line for line in text.splitlines() if line.startswith("objective: "))
    entry.write_text(text.replace(objective, "objective: 1.5"))
    result = runner.invoke(app, ["replay", str(entry)])
    assert result.exit_code == 1, result.output
    assert "replay does NOT match" in result.output
    assert runner.invoke(app, ["replay", str(entry), "--failure", "1"]).exit_code == 2


def test_a_run_someone_else_wrote_replays_only_with_trust(run, tmp_path, monkeypatch):
    fid = first_failure(run)
    copy = tmp_path / "theirs"
    shutil.copytree(run, copy)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "another-user"))  # its signature is not ours
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")  # and the plugin file its spec names lies outside our project
    result = runner.invoke(app, ["replay", str(copy), "--failure", str(fid)])
    assert result.exit_code == 2, result.output
    message = " ".join(result.output.split())
    assert "not started by you" in message and "--trust" in message, message

    result = runner.invoke(app, ["replay", str(copy), "--failure", str(fid), "--trust"])
    assert result.exit_code == 0, result.output
    assert "replay matches" in result.output

    result = runner.invoke(
        app, ["replay", str(run.parent / "toy.yaml"), "--theta", "0.6,0.05,0.6,0.05,0,0,0", "--trust"]
    )
    assert result.exit_code == 2 and "--trust" in result.output, result.output


def test_compare_is_exact_on_verdicts_and_tolerant_on_numbers():
    stored = {"status": "ok", "failure": True, "objective": 10.0, "measures": [0.1, None]}
    same = {"status": "ok", "failure": True, "objective": 10.0 + 0.5 * TOLERANCE, "measures": [0.1, None]}
    assert all(c.ok for c in compare(stored, same, ["a", "b"]))
    off = {**same, "measures": [0.1, 0.2]}
    assert [c.name for c in compare(stored, off, ["a", "b"]) if not c.ok] == ["b"]
    flipped = {**same, "failure": False}
    assert [c.name for c in compare(stored, flipped, ["a", "b"]) if not c.ok] == ["failure"]


def test_an_unknown_failure_id_lists_the_ids(run):
    failures = yaml.safe_load((run / "failures.yaml").read_text())["failures"]
    result = runner.invoke(app, ["replay", str(run), "--failure", "99999"])
    assert result.exit_code == 2
    assert "has no failure with id 99999" in result.output
    assert ", ".join(str(f["id"]) for f in failures[:3]) in result.output
    with pytest.raises(UnknownFailureError):
        replay_failure(run, 99999)


def test_bad_input_exits_2(run, tmp_path):
    fid = first_failure(run)
    cases = [
        (["replay", str(run)], "--failure"),  # a run needs --failure
        (["replay", str(tmp_path / "nothing")], "does not exist"),
        (["replay", str(tmp_path), "--failure", "1"], "run.json"),  # a folder that is not a run
        (["replay", str(SPECS / "teleop.yaml")], "--theta"),  # a spec needs --theta
        (["replay", str(SPECS / "teleop.yaml"), "--theta", "1,2"], "got 2 values"),
    ]
    (tmp_path / "file").write_text("")
    cases.append(
        (
            ["replay", str(run), "--failure", str(fid), "--out", str(tmp_path / "file" / "x.rrd")],
            "cannot write the recording",
        )
    )
    for args, message in cases:
        result = runner.invoke(app, args)
        assert result.exit_code == 2, (args, result.output)
        assert message in result.output, (args, result.output)
    assert not (tmp_path / "recordings").exists()  # nothing written for bad input


def test_any_scenario_of_a_spec_replays_deterministically(tmp_path):
    out = tmp_path / "teleop.rrd"
    result = runner.invoke(
        app,
        [
            "replay",
            str(SPECS / "teleop.yaml"),
            "--theta",
            "0.6,0.05,0.6,0.09,0,0,0,0,0",
            "--seed",
            "3",
            "--out",
            str(out),
        ],
    )
    assert result.exit_code == 0, result.output
    assert "a first simulation of the same theta and seed" in result.output
    entities = recorded_entities(out)
    assert {"world/arm/link3", "series/belief/goal0", "world/robot/ee", "world/object/goal0"} <= set(entities)
