"""Compiling a spec fixes theta's layout; binding theta gives a concrete scenario."""

from __future__ import annotations

import numpy as np
import pytest

from hritest.domain import compile_spec, load_domain
from hritest.errors import SpecError
from hritest.spec import load_spec


@pytest.fixture
def domain(toy_spec):
    return compile_spec(load_spec(toy_spec()))


def test_layout_follows_the_spec_order(domain):
    space = domain.space
    assert space.labels == ["g0x", "g0y", "g1x", "g1y", "noise[0]", "noise[1]", "noise[2]"]
    np.testing.assert_array_equal(space.lower, [0.52, -0.08, 0.52, -0.08, -0.05, -0.05, -0.05])
    np.testing.assert_array_equal(space.upper, [0.68, 0.18, 0.68, 0.18, 0.05, 0.05, 0.05])


def test_bind_sets_model_parameters(domain):
    theta = np.array([0.55, 0.1, 0.66, -0.02, 0.01, -0.02, 0.03])
    scenario = domain.space.bind(theta)
    assert (scenario.task["g0x"], scenario.task["g1y"]) == (0.55, -0.02)
    np.testing.assert_allclose(scenario.human["noise"], [0.01, -0.02, 0.03])
    assert scenario.human["speed"] == 1.0  # unbound: the plugin's default
    assert scenario.task["scale"] == 1.0 and scenario.task["fault"] == "none"
    assert scenario.values["g1y"] == -0.02
    assert scenario.objects == {} and scenario.bodies == {}
    # Binding does not alias theta.
    theta[4] = 0.0
    assert scenario.human["noise"][0] == 0.01


def test_the_task_gets_a_context_never_the_spec(domain):
    context = domain.context(domain.space.bind(domain.nominal))
    assert (context.dt, context.time_limit, context.ticks) == (0.025, 10.0, 400)
    assert context.params.g0x == 0.6 and context.world is None
    assert not hasattr(context, "spec")


def test_nominal_theta_is_the_specs_own_values(toy_spec):
    # Plugin defaults for task params, the middle of the bounds for the noise (its default [0, 0, 0]
    # happens to be that too), and an explicit nominal where given.
    domain = compile_spec(
        load_spec(
            toy_spec("bind: task.g1y, bounds: [-0.08, 0.18]}", "bind: task.g1y, bounds: [-0.08, 0.18], nominal: 0.1}")
        )
    )
    np.testing.assert_array_equal(domain.nominal, [0.6, 0.05, 0.6, 0.1, 0, 0, 0])


def test_a_nominal_outside_the_bounds_is_an_error(toy_spec):
    with pytest.raises(SpecError, match=r"parameters\[3\].*outside the bounds"):
        load_spec(
            toy_spec("bind: task.g1y, bounds: [-0.08, 0.18]}", "bind: task.g1y, bounds: [-0.08, 0.18], nominal: 1}")
        )


def test_bounds_the_plugin_rejects_are_an_error_at_compile_time(toy_spec, tmp_path):
    plugins = tmp_path / "toy_plugins.py"
    plugins.write_text(
        plugins.read_text()
        .replace("g1y: float = 0.05", "g1y: float = Field(0.05, ge=0)")
        .replace("from pydantic import BaseModel, ConfigDict", "from pydantic import BaseModel, ConfigDict, Field")
    )
    with pytest.raises(SpecError, match=r"parameters\[3\]\.bounds.*ToyTask.Params rejects g1y = -0.08"):
        compile_spec(load_spec(toy_spec()))


def test_repair_keeps_theta_within_the_bounds_without_a_bounds_constraint(toy_spec):
    domain = compile_spec(
        load_spec(toy_spec("constraints:\n  - {type: bounds, groups: [[g0x, g1x], [g0y, g1y], [noise]]}\n", ""))
    )
    repaired = domain.repair(np.array([0.9, 0.05, 0.6, 0.05, 0.2, 0, 0]))
    np.testing.assert_array_equal(repaired.theta, [0.68, 0.05, 0.6, 0.05, 0.05, 0, 0])


PLACED = """workspace:
  table: {center: [0.65, -0.175, 0.845], half_size: [0.2, 0.5, 0.021]}
objects:
  - {name: box, half_size: [0.03, 0.03, 0.03], position: [0.6, 0.05, 0.9]}
parameters:
  - {name: box_z, bind: box.z, bounds: [0.88, 1.0]}
  - {name: arm_yaw, bind: arm.yaw, bounds: [-0.5, 0.5]}
  - {name: arm_x, bind: arm.x, bounds: [0.3, 0.5]}
"""


def test_objects_and_the_arm_are_placed_in_the_tasks_world(toy_spec):
    domain = compile_spec(load_spec(toy_spec("parameters:\n", PLACED)))
    assert domain.space.labels[:3] == ["box_z", "arm_yaw", "arm_x"]
    np.testing.assert_allclose(domain.nominal[:3], [0.9, 0.0, 0.409])  # the spec's own values
    scenario = domain.space.bind(np.r_[0.95, 0.2, 0.45, domain.nominal[3:]])
    np.testing.assert_array_equal(scenario.objects["box"], [0.6, 0.05, 0.95])
    world = domain.context(scenario).world
    assert world.objects[0].center == (0.6, 0.05, 0.95)
    assert world.arm.yaw == 0.2 and world.arm.base == (0.45, 0.338, 0.795)
    assert domain.world.arm.base == (0.409, 0.338, 0.795)  # the domain's own layout is untouched


@pytest.mark.parametrize(
    ("old", "new", "words"),
    [
        ("bind: box.z", "bind: box.yaw", ["box.x, box.y, box.z", "not 'box.yaw'"]),
        ("bind: arm.x", "bind: arm.start", ["arm.start needs one angle per arm joint: set size: 6"]),
        ("bind: arm.x", "bind: door.x", ["unknown target 'door'", "world.model"]),
    ],
)
def test_world_bindings_are_checked(toy_spec, old, new, words):
    with pytest.raises(SpecError) as caught:
        compile_spec(load_spec(toy_spec("parameters:\n", PLACED.replace(old, new))))
    for word in words:
        assert word in str(caught.value)


def test_a_task_written_for_hritest_0_1_gets_a_migration_message(toy_spec, tmp_path):
    plugins = tmp_path / "toy_plugins.py"
    plugins.write_text(
        plugins.read_text()
        .replace(
            "def __init__(self, *, context: TaskContext) -> None:",
            "def __init__(self, *, params, scenario, spec) -> None:",
        )
        .replace("grids: ClassVar[dict[str, tuple[int, int]]] = {}", 'agents = ("robot",)')
    )
    with pytest.raises(SpecError) as caught:
        compile_spec(load_spec(toy_spec()))
    text = str(caught.value)
    assert "task.name" in text and "takes the spec (hritest 0.1)" in text and "context" in text
    assert "grids = {'robot': (32, 32)}" in text and "Migrating from hritest 0.1" in text


def test_bind_rejects_a_theta_of_the_wrong_length(domain):
    with pytest.raises(ValueError, match="7 components"):
        domain.space.bind(np.zeros(6))


def test_expressions_are_compiled(domain):
    assert domain.objective.evaluate({"completion_time": 3.0}) == 3.0
    variation = domain.measures[1].expression.evaluate({"noise": np.array([0.0, 0.03, 0.04])})
    assert variation == pytest.approx(0.05)
    assert domain.failure.evaluate({"objective": 9.0}) is True


ROOM = """<mujoco><worldbody>
  <body name="door" pos="1 0 0"><geom type="box" size="0.05 0.4 1"/></body>
</worldbody></mujoco>"""


def test_bodies_of_a_world_model_are_bound_by_name(toy_spec, tmp_path):
    (tmp_path / "room.xml").write_text(ROOM)
    spec = toy_spec(
        "parameters:\n",
        "world:\n  model: room.xml\nparameters:\n  - {name: door_x, bind: door.x, bounds: [0.5, 1.5], nominal: 1.0}\n",
    )
    domain = compile_spec(load_spec(spec))
    assert domain.world.model == str(tmp_path / "room.xml") and domain.world.arm is None
    world = domain.context(domain.space.bind(np.r_[1.25, domain.nominal[1:]])).world
    assert world.bodies["door"].x == 1.25 and world.bodies["door"].y is None


def test_an_unknown_body_of_the_world_model_is_named_with_the_known_ones(toy_spec, tmp_path):
    (tmp_path / "room.xml").write_text(ROOM)
    spec = toy_spec(
        "parameters:\n",
        "world:\n  model: room.xml\nparameters:\n  - {name: window_x, bind: window.x, bounds: [0.5, 1.5]}\n",
    )
    with pytest.raises(SpecError) as caught:
        compile_spec(load_spec(spec))
    text = str(caught.value)
    assert "parameters[0].bind:" in text and "no body named 'window'" in text and "door" in text


def test_load_domain_reports_every_independent_problem_at_once(toy_spec):
    path = toy_spec("  time_limit: 10.0\n", "  time_limit: 10.0\n  timelimit: 3\n")
    path.write_text(
        path.read_text()
        .replace("bind: task.g1x", "bind: goal9.x")
        .replace("policy: toy_plugins.py:ToyRobot", "policy: toy_plugins.py:Nope")
    )
    with pytest.raises(SpecError) as info:
        load_domain(path)
    assert [issue.field for issue in info.value.issues] == ["task.timelimit", "parameters[2].bind", "robot.policy"]
    assert "has no class 'Nope'" in info.value.issues[2].message


def test_load_domain_reports_plugins_beside_schema_errors(toy_spec):
    path = toy_spec("cells: 16}\n  - {name: variation", "cells: 0}\n  - {name: variation")
    path.write_text(path.read_text().replace("policy: toy_plugins.py:ToyHuman", "policy: nowhere.py:Human"))
    with pytest.raises(SpecError) as info:
        load_domain(path)
    assert [issue.field for issue in info.value.issues] == ["measures[0].cells", "human.policy"]


def test_params_every_plugin_rejects_are_reported_at_once(toy_spec):
    path = toy_spec("  time_limit: 10.0\n", "  time_limit: 10.0\n  params: {scale: fast, delay: never}\n")
    path.write_text(
        path.read_text().replace(
            "policy: toy_plugins.py:ToyHuman\n", "policy: toy_plugins.py:ToyHuman\n  params: {speed: slow}\n"
        )
    )
    with pytest.raises(SpecError) as info:
        load_domain(path)
    fields = [issue.field for issue in info.value.issues]
    assert fields == ["task.params.scale", "task.params.delay", "human.params.speed"], str(info.value)
