"""The simulation core: a kinematic MuJoCo arm driven by world-frame twists, and its scene."""

from hritest.sim.control import twist_to_joint_velocity
from hritest.sim.scene import world_layout
from hritest.sim.world import (
    DT,
    HAND_RADIUS,
    ROBOT_BASE,
    START_CONFIG,
    ArmModelError,
    Box,
    TwistStep,
    World,
    WorldLayout,
    shared_world,
)

__all__ = [
    "DT",
    "HAND_RADIUS",
    "ROBOT_BASE",
    "START_CONFIG",
    "ArmModelError",
    "Box",
    "TwistStep",
    "World",
    "WorldLayout",
    "shared_world",
    "twist_to_joint_velocity",
    "world_layout",
]
