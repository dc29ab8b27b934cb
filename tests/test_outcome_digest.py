"""The outcome digest: what decides an outcome changes it, part by part; comments and search settings do not."""

from __future__ import annotations

import json
import subprocess
import sys

from hritest.domain import compile_spec
from hritest.outcome_digest import outcome_digest
from hritest.spec import load_spec


def digest_of(path):
    return outcome_digest(compile_spec(load_spec(path)))


def changed(before, after) -> list[str]:
    return [name for name in before.parts if before.parts[name] != after.parts[name]]


def test_comments_formatting_and_search_settings_change_nothing(toy_spec):
    before = digest_of(toy_spec())
    text = toy_spec().read_text()
    edited = "# a comment\n" + text.replace("budget: 500", "budget: 20\n  seed: 9").replace(
        "failure: objective >= 8", "failure:   objective >= 8   # why"
    )
    after = digest_of(toy_spec(text=edited))
    assert after == before


def test_each_outcome_part_is_named_when_it_changes(toy_spec, tmp_path):
    before = digest_of(toy_spec())
    cases = {
        ("failure: objective >= 8", "failure: objective >= 9"): ["failure condition"],
        ("bounds: [0.52, 0.68]}\n  - {name: g0y", "bounds: [0.5, 0.68]}\n  - {name: g0y"): ["scenario space"],
        ("time_limit: 10.0", "time_limit: 12.0"): ["task"],
        ("expr: norm(noise)", "expr: human_variation"): ["measures"],
        ("{type: bounds, groups: [[g0x, g1x], [g0y, g1y], [noise]]}", "{type: bounds}"): ["constraints"],
        ("constraints:\n", "repair: {units: raw}\nconstraints:\n"): ["repair"],
    }
    for (old, new), parts in cases.items():
        assert changed(before, digest_of(toy_spec(old, new))) == parts, (old, new)

    plugins = tmp_path / "toy_plugins.py"
    plugins.write_text(plugins.read_text().replace("scale: float = 1.0", "scale: float = 0.7"))
    # every class of the edited file: the three plugins live in it (a fresh process loads the new file)
    code = (
        "import sys, json; from hritest.domain import compile_spec; from hritest.spec import load_spec; "
        "from hritest.outcome_digest import outcome_digest; "
        f"print(json.dumps(dict(outcome_digest(compile_spec(load_spec({str(toy_spec())!r}))).parts)))"
    )
    parts = json.loads(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout)
    assert [n for n in before.parts if before.parts[n] != parts[n]] == [
        "task plugin source",
        "robot plugin source",
        "human plugin source",
    ]


def test_an_installed_plugin_package_is_digested_whole():
    from hritest.outcome_digest import _source
    from hritest.plugin_loader import resolve

    # hindsight assistance imports helpers from the package's other modules: all of them count
    cls = resolve("hindsight", kind="robot")
    assert cls.__module__.startswith("hritest_plugins")
    assert _source(cls) == _source(resolve("waypoint_teleop", kind="human"))
