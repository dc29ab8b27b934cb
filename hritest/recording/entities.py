"""The names a recording logs under: its application id, timeline, world frame and entity paths."""

from __future__ import annotations

APPLICATION_ID = "hritest"
TIMELINE = "sim_time"
WORLD_FRAME = "tf#/world"  # rerun's implicit frame of the entity ``world``


def entity_path(root: str, name: str) -> str:
    """``root/name`` with each ``/``-separated part of ``name`` escaped for rerun."""
    import rerun as rr

    return rr.new_entity_path([root, *(part for part in str(name).split("/") if part)])
