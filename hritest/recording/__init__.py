"""Rerun recordings of simulated scenarios: every call to ``rerun`` in hritest lives in this package.

Rerun's Python API has renamed things from one release to the next (``timeless`` became
``static``, ``Scalar`` became ``Scalars``, ``set_time_*`` became ``set_time``), so keeping every
call in one package keeps an upgrade to its few files. Written against rerun-sdk 0.41.

A recording draws what the task simulated and reported in its :class:`hritest.protocols.Rollout`,
nothing rebuilt from the spec: it assumes no table, goal or arm. One ``.rrd`` holds one scenario,
application id ``hritest``, recording id the scenario digest, timeline ``sim_time`` in simulated
seconds. Names from the rollout keep their ``/`` (it groups entities in the viewer); each part
is escaped. Entities:

==============================  =======================================================
``world``                       right-handed, z up; the 3D view's origin
``world/<body>``                each body of the traced MuJoCo world (``Rollout.scene``):
                                its world pose (``Transform3D`` into ``tf#/world``), per
                                tick for bodies that move, once (static) for the others
``world/<body>/geoms``          its geoms, in its frame (static): boxes and planes as
                                ``Boxes3D``, spheres and ellipsoids as ``Ellipsoids3D``,
                                ``Capsules3D``, ``Cylinders3D``, meshes as one ``Mesh3D``
``world/<name>``                each of ``Rollout.trajectories``: a point per tick
``world/<name>/path``           its whole path (static line strip)
``series/<name>``               each of ``Rollout.series``: a scalar per tick
``states/<agent>``              each agent's state machine, logged when it changes
``events``                      the task's events, and the verdict at the episode's end
``grids/<name>``                each of ``Rollout.grids`` (static image, x right, y up)
``scenario``                    objective, measures, metrics and theta (static document)
==============================  =======================================================

A recording of several episodes (a failure beside the nearest scenario that passes,
:func:`write_episodes`) puts each under its name, ``<episode>/world/...`` and so on, on one
timeline.

Bodies and trajectories are placed in the ``world`` frame explicitly (``parent_frame`` and
``CoordinateFrame``), not through the entity tree: a body ``arm/link3`` or a trajectory
``robot/ee`` must not inherit the pose of a body called ``arm`` or ``robot``.
"""

from hritest.recording.entities import APPLICATION_ID, TIMELINE, WORLD_FRAME
from hritest.recording.files import RecordingError, check_writable, open_viewer, recorded_entities, recording_ids
from hritest.recording.write import Episode, grid_image, write_episodes, write_recording

__all__ = [
    "APPLICATION_ID",
    "TIMELINE",
    "WORLD_FRAME",
    "Episode",
    "RecordingError",
    "check_writable",
    "grid_image",
    "open_viewer",
    "recorded_entities",
    "recording_ids",
    "write_episodes",
    "write_recording",
]
