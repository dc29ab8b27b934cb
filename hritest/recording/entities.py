"""The names a recording logs under: its application id, timeline, world frame and entity paths."""

from __future__ import annotations

APPLICATION_ID = "hritest"
TIMELINE = "sim_time"
WORLD_FRAME = "tf#/world"  # rerun's implicit frame of the entity ``world``


def entity_path(root: str, name: str) -> str:
    """``root/name`` with each ``/``-separated part of ``name`` escaped for rerun (``root`` is
    hritest's own, e.g. ``world`` or ``passing/world``)."""
    import rerun as rr

    return rr.new_entity_path([*root.split("/"), *(part for part in str(name).split("/") if part)])


def under(episode: str, root: str) -> str:
    """Where ``root`` (``world``, ``series``, ...) lies for an episode: itself for a recording of one
    episode (``episode`` empty), ``episode/root`` for one of several."""
    return f"{episode}/{root}" if episode else root


def world_frame(episode: str) -> str:
    """The implicit frame of an episode's ``world`` entity."""
    return f"tf#/{under(episode, 'world')}"
