"""The simulation core: a kinematic MuJoCo arm driven by world-frame twists, and its scene.

The plain-data layouts (:mod:`hritest.sim.layout`) import without MuJoCo; the world and the
controller are imported on first use, so loading a spec or a plugin contract never pays for
importing ``mujoco`` and numba's kernels.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from hritest.sim.layout import ROBOT_BASE, START_CONFIG, ArmMount, BodyPose, Box, SceneTrace, WorldLayout

if TYPE_CHECKING:
    from hritest.sim.control import twist_to_joint_velocity
    from hritest.sim.mjcf import HAND_RADIUS, ArmModelError, WorldModelError
    from hritest.sim.scene_replay import Geom, SceneReplay
    from hritest.sim.world import DT, TwistStep, World, shared_world

_LAZY = {
    "twist_to_joint_velocity": "hritest.sim.control",
    **dict.fromkeys(("HAND_RADIUS", "ArmModelError", "WorldModelError"), "hritest.sim.mjcf"),
    **dict.fromkeys(("Geom", "SceneReplay"), "hritest.sim.scene_replay"),
    **dict.fromkeys(("DT", "TwistStep", "World", "shared_world"), "hritest.sim.world"),
}


def __getattr__(name: str) -> object:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'hritest.sim' has no attribute {name!r}")


__all__ = [
    "DT",
    "HAND_RADIUS",
    "ROBOT_BASE",
    "START_CONFIG",
    "ArmModelError",
    "ArmMount",
    "BodyPose",
    "Box",
    "Geom",
    "SceneReplay",
    "SceneTrace",
    "TwistStep",
    "World",
    "WorldLayout",
    "WorldModelError",
    "shared_world",
    "twist_to_joint_velocity",
]
