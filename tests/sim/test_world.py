"""The MuJoCo world: the arm's kinematics, reach, limits, collisions and determinism; scene
models, arm mounts, other arms, traces and replays."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hritest.errors import HritestError
from hritest.sim import (
    DT,
    ROBOT_BASE,
    START_CONFIG,
    ArmModelError,
    ArmMount,
    BodyPose,
    Box,
    SceneReplay,
    World,
    WorldLayout,
    WorldModelError,
    shared_world,
)

R_GOAL = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
R_GOAL_TURNED = np.diag([-1.0, -1.0, 1.0]) @ R_GOAL  # the second target: 180 deg about world z
BASE = np.array([0.409, 0.338, 0.795])
WORKSPACES = {"ws1": ((0.52, 0.68), (-0.08, 0.18)), "ws2": ((0.138, 0.298), (0.496, 0.756))}
START_EE = np.array([0.41, 0.05, 0.96])
PERSISTING = 40  # ticks (1 s) of limit_reached in a row: the arm is stuck, not passing by


def reference_layout(**changes) -> WorldLayout:
    """The reference's scene: side table, the two workspace slabs, two goal boxes, a hand."""
    fields = {
        "table": Box(name="table", center=(0.65, -0.175, 0.845), half_size=(0.2, 0.5, 0.021)),
        "regions": (
            Box(name="ws1", center=(0.595, 0.05, 0.86), half_size=(0.13, 0.18, 0.021)),
            Box(name="ws2", center=(0.22, 0.625, 0.86), half_size=(0.13, 0.18, 0.021)),
        ),
        "objects": (
            Box(name="goal0", center=(0.6, 0.05, 0.96), half_size=(0.032,) * 3),
            Box(name="goal1", center=(0.218, 0.626, 0.96), half_size=(0.032,) * 3),
        ),
        "hand_start": (0.91, 0.05, 0.96),
    }
    return WorldLayout(**(fields | changes))


@pytest.fixture(scope="module")
def world() -> World:
    return World(layout=reference_layout())


@pytest.fixture
def fresh(world: World) -> World:
    world.reset()
    return world


def rotation_error(current: np.ndarray, target: np.ndarray) -> np.ndarray:
    """World-frame rotation vector taking ``current`` to ``target``."""
    return Rotation.from_matrix(target @ current.T).as_rotvec()


def test_start_pose_is_where_the_operator_starts(fresh: World):
    # Documented in hritest.sim.arm: within 1 mm of (0.41, 0.05, 0.96) and 0.1 deg of R_goal.
    pose = fresh.ee_pose()
    assert np.linalg.norm(pose[:3, 3] - START_EE) < 1e-3
    assert np.linalg.norm(rotation_error(pose[:3, :3], R_GOAL)) < np.radians(0.1)
    np.testing.assert_array_equal(fresh.q, START_CONFIG)
    assert not fresh.self_collision()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_jacobian_matches_finite_differences(world: World, seed: int):
    rng = np.random.default_rng(seed)
    q0 = np.array(START_CONFIG) + (rng.uniform(-0.5, 0.5, 6) if seed else 0.0)
    world.set_q(q0)
    jacobian, h = world.jacobian(), 1e-6
    numeric = np.empty((6, 6))
    for i in range(6):
        step = np.eye(6)[i] * h
        world.set_q(q0 + step)
        plus = world.ee_pose()
        world.set_q(q0 - step)
        minus = world.ee_pose()
        numeric[:3, i] = (plus[:3, 3] - minus[:3, 3]) / (2 * h)
        numeric[3:, i] = rotation_error(minus[:3, :3], plus[:3, :3]) / (2 * h)
    np.testing.assert_allclose(jacobian, numeric, atol=1e-5)


@pytest.mark.parametrize("direction", [(1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (1, 1, 0)])
def test_constant_twist_moves_the_ee_along_a_straight_line(fresh: World, direction):
    line = np.array(direction, dtype=float) / np.linalg.norm(direction)
    start = fresh.ee_pose()
    for _ in range(int(2.0 / DT)):
        assert not fresh.step_twist(np.r_[0.05 * line, 0, 0, 0]).limit_reached
    end = fresh.ee_pose()
    moved = end[:3, 3] - start[:3, 3]
    assert moved @ line == pytest.approx(0.1, abs=1e-3)
    assert np.linalg.norm(moved - (moved @ line) * line) < 1e-3
    assert np.linalg.norm(rotation_error(start[:3, :3], end[:3, :3])) < np.radians(0.5)


def _rotation_command(pose: np.ndarray, target: np.ndarray, goal: np.ndarray) -> np.ndarray:
    # Near a half turn the direction of the rotation error is decided by rounding; turn the hand
    # the way the arm swings about its base, so wrist and base do not fight each other.
    error = rotation_error(pose[:3, :3], target)
    angle = np.linalg.norm(error)
    if angle > np.pi - 0.2:
        swing = np.cross(pose[:3, 3] - BASE, goal - BASE)[2]
        if error[2] * swing < 0:
            error = -error * (2 * np.pi - angle) / angle
    return error


def _clip(vector: np.ndarray, largest: float) -> np.ndarray:
    norm = np.linalg.norm(vector)
    return vector * min(1.0, largest / norm) if norm > 0 else vector


def _drive_to(world: World, goal: np.ndarray, target: np.ndarray) -> tuple[bool, int]:
    """Proportional twist control (gain 2/s, capped at 0.25 m/s and 1 rad/s) for at most 20 s.

    Returns whether the pose was reached (1 cm, pi/48) and the longest run of limit_reached ticks.
    """
    world.reset()
    run = longest = 0
    for _ in range(int(20.0 / DT)):
        pose = world.ee_pose()
        error = goal - pose[:3, 3]
        turn = _rotation_command(pose, target, goal)
        if np.linalg.norm(error) < 0.01 and np.linalg.norm(turn) < np.pi / 48:
            return True, longest
        step = world.step_twist(np.r_[_clip(2 * error, 0.25), _clip(2 * turn, 1.0)])
        run = run + 1 if step.limit_reached else 0
        longest = max(longest, run)
    return False, longest


def _workspace_points() -> list:
    points = []
    for name, (xs, ys) in WORKSPACES.items():
        corners = [(x, y) for x in xs for y in ys]
        for x, y in [*corners, (np.mean(xs), np.mean(ys))]:
            points.append(pytest.param(np.array([x, y, 0.96]), id=f"{name}-{x:.3f}-{y:.3f}"))
    return points


@pytest.mark.parametrize("goal", _workspace_points())
def test_every_workspace_corner_and_centre_is_reachable_from_the_start(world: World, goal):
    outcomes = []
    for target in (R_GOAL, R_GOAL_TURNED):
        reached, longest = _drive_to(world, goal, target)
        outcomes.append((reached, longest))
        if reached and longest < PERSISTING:
            return
    pytest.fail(f"neither target orientation reached: (reached, longest limit run) = {outcomes}")


def test_velocity_and_joint_limits_hold_under_random_twists(fresh: World):
    rng = np.random.default_rng(7)
    lower, upper = fresh.joint_limits
    speeds = fresh.velocity_limits
    for _ in range(2000):
        step = fresh.step_twist(rng.normal(0.0, [0.3, 0.3, 0.3, 1.0, 1.0, 1.0]))
        assert np.all(np.abs(step.qdot) <= 0.95 * speeds + 1e-12)
        assert np.all(fresh.q >= lower - 1e-8) and np.all(fresh.q <= upper + 1e-8)


def test_driving_joint_2_into_its_limit_reports_it(fresh: World):
    # Straight down from the start, the shoulder (joint 2) tilts until its upper limit stops it.
    upper = fresh.joint_limits[1][1]
    flagged = []
    for _ in range(300):
        flagged.append(fresh.step_twist([0.0, 0.0, -0.1, 0.0, 0.0, 0.0]).limit_reached)
        assert fresh.q[1] <= upper + 1e-8
    assert any(flagged)
    assert upper - fresh.q[1] < 0.03 and flagged[-1]


def test_limits_are_the_references(world: World):
    lower, upper = world.joint_limits
    np.testing.assert_array_equal(lower, [-np.inf, -3.845, -4.104, -np.inf, -np.inf, -np.inf])
    np.testing.assert_array_equal(upper, [np.inf, 0.704, 0.958, np.inf, np.inf, np.inf])
    assert np.all((world.velocity_limits > 0.83) & (world.velocity_limits < 0.84))


@pytest.mark.parametrize(
    "q",
    [
        pytest.param((-2.38, 0.0, -0.28, -0.75, 0.0, 3.55), id="hand-into-table"),
        pytest.param((-2.38, 0.704, -0.28, -0.75, 0.0, 3.55), id="arm-onto-pedestal"),
        pytest.param((-2.38, -0.43, -4.05, 3.14, -1.57, 3.55), id="hand-into-upper-arm"),
    ],
)
def test_folded_configurations_collide(world: World, q):
    world.set_q(q)
    assert world.self_collision()


def test_goal_boxes_and_hand_never_collide_with_the_arm():
    at_ee = tuple(START_EE)
    world = World(
        layout=reference_layout(objects=(Box(name="goal", center=at_ee, half_size=(0.032,) * 3),), hand_start=at_ee)
    )
    assert not world.self_collision()


def test_same_twists_give_bit_identical_joints(world: World):
    twists = np.random.default_rng(3).normal(0.0, 0.1, (400, 6))

    def run(w: World) -> np.ndarray:
        w.reset()
        for twist in twists:
            w.step_twist(twist)
        return w.q

    first = run(world)
    np.testing.assert_array_equal(first, run(world))
    np.testing.assert_array_equal(first, run(World(layout=reference_layout())))


def moved_goals(x: float) -> WorldLayout:
    return reference_layout(objects=(Box(name="goal0", center=(x, 0.05, 0.96), half_size=(0.032,) * 3),))


def test_a_shared_world_is_reused_for_new_goal_positions_and_behaves_as_a_fresh_one():
    twists = np.random.default_rng(5).normal(0.0, 0.1, (200, 6))

    def run(w: World) -> np.ndarray:
        for twist in twists:
            w.step_twist(twist)
        return w.q

    first = shared_world(moved_goals(0.6))
    run(first)
    again = shared_world(moved_goals(0.55))  # only a goal box moved: the same world, reset
    assert again is first and again.layout == moved_goals(0.55)
    np.testing.assert_array_equal(again.q, START_CONFIG)
    np.testing.assert_array_equal(run(again), run(World(layout=moved_goals(0.55))))
    assert shared_world(reference_layout(hand_start=None)) is not first  # a fixed part changed


def test_show_refuses_anything_a_reset_cannot_set(world: World):
    with pytest.raises(ValueError, match="only change what a reset sets"):
        world.show(reference_layout(hand_start=None))


def test_reset_restores_the_start_and_the_hand(world: World):
    world.step_twist([0.05, 0.0, 0.0, 0.0, 0.0, 0.0])
    world.set_hand([0.7, 0.2, 0.96])
    np.testing.assert_array_equal(world.hand_position(), [0.7, 0.2, 0.96])
    world.reset()
    np.testing.assert_array_equal(world.q, START_CONFIG)
    np.testing.assert_array_equal(world.hand_position(), [0.91, 0.05, 0.96])


def test_link_poses_name_every_arm_body(fresh: World):
    poses = fresh.link_poses()
    assert list(poses) == ["pedestal", *(f"link{i}" for i in range(1, 7))]
    np.testing.assert_allclose(poses["pedestal"][:3, 3], BASE)
    np.testing.assert_allclose(poses["link1"][:3, 3], BASE + [0, 0, 0.1], atol=1e-12)
    assert all(pose.shape == (4, 4) for pose in poses.values())


def test_a_world_without_a_hand_says_so():
    world = World(layout=reference_layout(hand_start=None))
    with pytest.raises(HritestError, match="no hand"):
        world.hand_position()


ONE_LINK_ARM = """<mujoco><compiler angle="radian"/><worldbody>
  <body name="upper"><joint name="swing" axis="0 0 1"/>
    <geom type="capsule" fromto="0 0 0.05 0.3 0 0.05" size="0.02"/>
    <body name="lower" pos="0.3 0 0.05"><joint name="bend" axis="0 1 0" range="-1 1"/>
      <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02"/><site name="tip" pos="0.2 0 0"/>
    </body></body></worldbody>
  {custom}</mujoco>"""
VELOCITIES = '<custom><numeric name="velocity_limits" data="1 1"/></custom>'


def test_a_users_arm_file_drives_the_world(tmp_path):
    path = tmp_path / "arm.xml"
    path.write_text(ONE_LINK_ARM.format(custom=VELOCITIES))
    world = World(layout=reference_layout(arm=ArmMount(mjcf=str(path), ee_site="tip", start=(0, 0))))
    assert world.joint_names == ("swing", "bend")
    np.testing.assert_allclose(world.ee_pose()[:3, 3], BASE + [0.5, 0, 0.05])
    assert world.jacobian().shape == (6, 2)
    np.testing.assert_array_equal(world.joint_limits[0], [-np.inf, -1.0])
    step = world.step_twist([0.0, 0.05, 0.0, 0.0, 0.0, 0.0])
    assert step.qdot[0] > 0  # a 2-joint arm resolves the twist in the least-squares sense


@pytest.mark.parametrize(
    ("custom", "site", "start", "message"),
    [
        ("", "tip", (0, 0), "velocity_limits"),
        (VELOCITIES, "ee", (0, 0), r"no site named 'ee' \(its sites: 'tip'\); set world.arm.ee_site"),
        (VELOCITIES, "tip", (0, 0, 0), r"start has 3 angles, but the arm .* has 2 hinge joints \(swing, bend\)"),
    ],
)
def test_an_unusable_arm_file_is_explained(tmp_path, custom, site, start, message):
    path = tmp_path / "arm.xml"
    path.write_text(ONE_LINK_ARM.format(custom=custom))
    with pytest.raises(ArmModelError, match=message) as error:
        World(layout=reference_layout(arm=ArmMount(mjcf=str(path), ee_site=site, start=start)))
    assert str(path) in str(error.value)


def test_a_users_arm_starts_at_its_files_qpos0(tmp_path):
    path = tmp_path / "arm.xml"
    path.write_text(ONE_LINK_ARM.format(custom=VELOCITIES).replace('axis="0 1 0"', 'axis="0 1 0" ref="0.5"'))
    world = World(layout=reference_layout(arm=ArmMount(mjcf=str(path), ee_site="tip")))
    np.testing.assert_array_equal(world.q, [0.0, 0.5])


def test_box_checks_its_sizes():
    with pytest.raises(ValueError, match="half_size needs 3 numbers"):
        Box(name="bad", center=(0, 0, 0), half_size=(1, 1))


CAPSULE7 = str(Path(__file__).parents[2] / "specs" / "models" / "capsule7_arm.xml")
CAPSULE7_START = (0.0, 0.4, 0.0, 1.6, 0.0, -0.4, 0.0)  # as the file's header says
SCENE = """<mujoco model="room">
  <compiler angle="degree"/>
  <default><geom rgba="0.8 0.2 0.2 1" group="3"/></default>
  <asset><mesh name="wedge" vertex="0 0 0  0.2 0 0  0 0.2 0  0 0 0.2"/></asset>
  <worldbody>
    <body name="chair" pos="1 2 0" euler="0 0 90">
      <geom name="seat" type="box" size="0.2 0.2 0.02" group="0"/>
      <geom name="seat_collision" type="box" size="0.21 0.21 0.03"/>
      <geom name="ghost" type="sphere" size="0.1" group="0" rgba="1 1 1 0"/>
      <geom name="cushion" type="mesh" mesh="wedge" group="1" pos="0 0 0.05"/>
    </body>
    <body name="cart" pos="-1 0 0.1"><freejoint/><geom type="box" size="0.1 0.1 0.1" group="2"/></body>
    <body name="human" pos="0 -1 0"><joint name="waist" axis="0 0 1" range="-90 90"/>
      <geom type="capsule" size="0.1 0.4" group="0"/>
    </body>
  </worldbody>
</mujoco>"""


def rz(yaw: float) -> np.ndarray:
    return Rotation.from_euler("z", yaw).as_matrix()


@pytest.fixture
def scene(tmp_path) -> str:
    path = tmp_path / "room.xml"
    path.write_text(SCENE)
    return str(path)


def capsule7(**mount) -> World:
    return World(layout=WorldLayout(arm=ArmMount(mjcf=CAPSULE7, start=CAPSULE7_START, **mount)))


def test_capsule7_starts_where_its_file_says():
    world = capsule7(base=(0.0, 0.0, 0.0))
    pose = world.ee_pose()
    np.testing.assert_allclose(pose[:3, 3], [0.5285, 0.0, 0.5407], atol=1e-4)
    assert np.degrees(np.arccos(pose[2, 2])) == pytest.approx(91.7, abs=0.05)  # tool z: +x, a little down
    assert world.joint_names == tuple(f"joint{i}" for i in range(1, 8))
    assert np.all(np.isfinite(world.joint_limits[0])) and len(world.velocity_limits) == 7
    assert not world.self_collision()


@pytest.mark.parametrize("direction", [(1, 0, 0), (0, 1, 0), (0, 0, -1), (-1, 1, 1)])
def test_a_7_dof_arm_follows_a_twist(direction):
    world = capsule7()
    line = np.array(direction, dtype=float) / np.linalg.norm(direction)
    twist = np.r_[0.05 * line, 0.0, 0.0, 0.0]
    start, jacobian = world.ee_pose(), world.jacobian()
    assert jacobian.shape == (6, 7)
    # Redundant: of all joint velocities giving the twist, the resolved one is the smallest.
    np.testing.assert_allclose(world.step_twist(twist).qdot, np.linalg.pinv(jacobian) @ twist, atol=1e-12)
    for _ in range(int(1.0 / DT) - 1):
        assert not world.step_twist(twist).limit_reached
    moved = world.ee_pose()[:3, 3] - start[:3, 3]
    assert moved @ line == pytest.approx(0.05, abs=5e-4)
    assert np.linalg.norm(moved - (moved @ line) * line) < 5e-4
    assert np.linalg.norm(rotation_error(start[:3, :3], world.ee_pose()[:3, :3])) < np.radians(0.5)


@pytest.mark.parametrize(("mjcf", "start"), [(None, None), (CAPSULE7, CAPSULE7_START)], ids=["built-in", "capsule7"])
def test_a_moved_and_yawed_base_moves_the_ee_by_exactly_that_transform(mjcf, start):
    base, yaw = np.array([0.3, -0.2, 0.7]), 0.9
    at_origin = World(layout=WorldLayout(arm=ArmMount(mjcf=mjcf, base=(0.0, 0.0, 0.0), start=start)))
    moved = World(layout=WorldLayout(arm=ArmMount(mjcf=mjcf, base=tuple(base), yaw=yaw, start=start)))
    mount = np.eye(4)
    mount[:3, :3], mount[:3, 3] = rz(yaw), base
    np.testing.assert_allclose(moved.ee_pose(), mount @ at_origin.ee_pose(), atol=1e-12)
    turn = np.kron(np.eye(2), rz(yaw))  # world-frame twists turn with the base
    np.testing.assert_allclose(moved.jacobian(), turn @ at_origin.jacobian(), atol=1e-12)


def test_the_built_in_arm_stands_at_the_reference_base_by_default():
    assert ArmMount().base == ROBOT_BASE == tuple(BASE)
    np.testing.assert_allclose(World(layout=WorldLayout()).ee_pose()[:3, 3], START_EE, atol=1e-3)


def replay_now(world: World) -> SceneReplay:
    """The world's state now, traced for one tick and replayed."""
    tracer = world.tracer()
    tracer.capture()
    return SceneReplay(trace=tracer.finish())


def body_pose(replay: SceneReplay, name: str, tick: int = 0) -> tuple[np.ndarray, np.ndarray]:
    positions, quats = replay.poses(tick)
    i = replay.bodies.index(name)
    return positions[i], Rotation.from_quat(quats[i], scalar_first=True).as_matrix()


def test_a_scene_body_moved_by_a_body_pose_lands_there(scene):
    poses = {"chair": BodyPose(x=0.5, z=0.1, yaw=np.pi / 2), "cart": BodyPose(x=2.0, y=1.0, z=0.3, yaw=0.4)}
    world = World(layout=WorldLayout(model=scene, bodies=poses, table=None, arm=None))
    replay = replay_now(world)
    position, rotation = body_pose(replay, "chair")
    np.testing.assert_allclose(position, [0.5, 2.0, 0.1])  # y kept from the file
    np.testing.assert_allclose(rotation, rz(np.pi), atol=1e-12)  # the file's 90 degrees, turned 90 more
    position, rotation = body_pose(replay, "cart")  # a free body: its joint's reset pose moves
    np.testing.assert_allclose(position, [2.0, 1.0, 0.3])
    np.testing.assert_allclose(rotation, rz(0.4), atol=1e-12)


def test_a_scene_model_joins_the_world_with_its_own_joints(scene):
    world = World(layout=reference_layout(model=scene))
    assert world.joint_names == tuple(f"joint{i}" for i in range(1, 7))  # not the scene's waist
    np.testing.assert_array_equal(world.joint_limits[1], [np.inf, 0.704, 0.958, np.inf, np.inf, np.inf])  # radians
    np.testing.assert_array_equal(world.q, START_CONFIG)
    np.testing.assert_allclose(world.ee_pose()[:3, 3], START_EE, atol=1e-3)
    replay = replay_now(world)
    kinds = {(geom.body, geom.kind) for geom in replay.geoms}
    assert {
        ("world", "box"),
        ("chair", "box"),
        ("chair", "mesh"),
        ("human", "capsule"),
        ("hand", "sphere"),
        ("object/goal0", "box"),
        ("arm/link1", "capsule"),
    } <= kinds
    chair = [geom for geom in replay.geoms if geom.body == "chair"]
    assert len(chair) == 2  # the group-3 collision box and the transparent sphere are not drawn
    mesh = next(geom for geom in chair if geom.kind == "mesh")
    assert mesh.vertices.shape == (4, 3) and mesh.faces.shape[1] == 3
    table = next(geom for geom in replay.geoms if geom.body == "world")
    assert table.size == (0.2, 0.5, 0.021) and table.pos == (0.65, -0.175, 0.845)  # not hidden by the scene's defaults


def test_scene_replay_poses_at_each_tick_are_the_worlds(scene):
    world = World(layout=reference_layout(model=scene, arm=ArmMount(base=(0.4, 0.3, 0.8), yaw=0.3)))
    tracer, expected = world.tracer(), []
    twists = np.random.default_rng(2).normal(0.0, 0.1, (15, 6))
    for k, twist in enumerate(twists):
        world.step_twist(twist)
        world.set_hand([0.9 - 0.01 * k, 0.05, 0.96])
        tracer.capture()
        expected.append((world.link_poses(), world.hand_position()))
    trace = tracer.finish()
    assert trace.layout is world.layout and trace.mocap_pos.shape == (15, 3, 3)  # two goals and the hand
    replay = SceneReplay(trace=trace)
    assert replay.ticks == 15
    for k in (0, 7, 14):
        links, hand = expected[k]
        np.testing.assert_array_equal(body_pose(replay, "hand", k)[0], hand)
        for name in ("link1", "link6"):
            position, rotation = body_pose(replay, "arm/" + name, k)
            np.testing.assert_array_equal(position, links[name][:3, 3])
            np.testing.assert_allclose(rotation, links[name][:3, :3], atol=1e-12)


def test_a_shared_world_switches_poses_mount_and_hand_without_recompiling(scene):
    first = reference_layout(model=scene, bodies={"chair": BodyPose(x=0.2)})
    second = reference_layout(
        model=scene,
        bodies={"chair": BodyPose(y=0.5, yaw=0.3), "human": BodyPose(z=0.2)},
        arm=ArmMount(base=(0.3, 0.3, 0.7), yaw=-0.5, start=(-2.0, -0.4, -0.3, -0.7, 0.1, 3.5)),
        hand_start=(0.8, 0.1, 0.9),
        objects=(
            Box(name="goal0", center=(0.5, 0.1, 0.96), half_size=(0.032,) * 3),
            Box(name="goal1", center=(0.2, 0.6, 0.96), half_size=(0.032,) * 3),
        ),
    )
    world = shared_world(first)
    world.step_twist([0.05, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert shared_world(second) is world
    for layout in (second, first):  # and back: what the second moved returns to the file's place
        shared = shared_world(layout)
        assert shared is world and shared.layout == layout
        fresh = World(layout=layout)
        np.testing.assert_array_equal(shared.q, fresh.q)
        np.testing.assert_array_equal(shared.ee_pose(), fresh.ee_pose())
        np.testing.assert_array_equal(replay_now(shared).poses(0)[0], replay_now(fresh).poses(0)[0])


def test_a_world_without_an_arm_says_so(scene):
    world = World(layout=WorldLayout(model=scene, arm=None, hand_start=(0.5, 0.0, 1.0)))
    np.testing.assert_array_equal(world.hand_position(), [0.5, 0.0, 1.0])
    for use in (
        world.ee_pose,
        world.jacobian,
        lambda: world.step_twist(np.zeros(6)),
        lambda: world.set_q([0.0]),
        lambda: world.q,
    ):
        with pytest.raises(HritestError, match=r"no arm: set world\.arm in the spec"):
            use()


def test_an_unknown_body_is_explained_with_the_files_bodies(scene):
    with pytest.raises(
        WorldModelError,
        match=r"room\.xml has no body named 'sofa'; its named bodies: chair, cart, "
        r"human\. Fix the parameter that binds sofa\.x",
    ):
        World(layout=WorldLayout(model=scene, bodies={"sofa": BodyPose(x=1.0)}))
    with pytest.raises(WorldModelError, match="the world has no model file"):
        World(layout=WorldLayout(bodies={"sofa": BodyPose(x=1.0)}))


def test_show_with_an_unknown_body_changes_nothing(scene):
    layout = WorldLayout(model=scene, bodies={"chair": BodyPose(x=0.3)})
    world = World(layout=layout)
    with pytest.raises(WorldModelError, match="no body named 'sofa'"):
        world.show(WorldLayout(model=scene, bodies={"sofa": BodyPose(x=1.0)}))
    assert world.layout is layout


@pytest.mark.parametrize("part", ["model", "arm"])
@pytest.mark.parametrize(
    ("content", "message"), [(None, "Error opening file"), ("<mujoco><worldbody>", "XML parse error")]
)
def test_a_missing_or_broken_file_is_named(tmp_path, part, content, message):
    path = tmp_path / "missing.xml"
    if content is not None:
        path.write_text(content)
    layout = WorldLayout(model=str(path)) if part == "model" else WorldLayout(arm=ArmMount(mjcf=str(path)))
    with pytest.raises(WorldModelError, match=f"Cannot load the .*world.{part}.* {re.escape(str(path))}: .*{message}"):
        World(layout=layout)


def test_a_scene_body_named_like_hritests_own_is_refused(tmp_path):
    path = tmp_path / "room.xml"
    path.write_text(SCENE.replace('name="human"', 'name="hand"'))
    with pytest.raises(WorldModelError, match=r"room\.xml has bodies named 'hand'.*rename them in the file"):
        World(layout=WorldLayout(model=str(path)))
