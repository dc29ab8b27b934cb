"""Recording files: where one can be written, what one holds (read back), and the viewer."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path

from hritest.errors import HritestError
from hritest.recording.entities import TIMELINE


class RecordingError(HritestError):
    """A recording that cannot be written where it was asked for."""


def check_writable(path: Path) -> Path:
    """Makes ``path``'s folder and checks that a file can be created there.

    Raises:
        RecordingError: the folder cannot be made or written, or ``path`` is a folder.
    """
    path = Path(path)
    if path.is_dir():
        raise RecordingError(f"{path} is a folder; give a file path for the recording, e.g. {path / 'failure.rrd'}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise RecordingError(f"cannot write the recording {path}: {exc.strerror or exc}") from None
    return path


def recorded_entities(path: Path) -> Mapping[str, Sequence[float]]:
    """Entity path -> the ``sim_time`` points (seconds) logged to it; static entities map to ``()``.

    For tests and for checking a recording without a viewer.
    """
    from rerun.chunk import RrdReader

    found: dict[str, list[float]] = {}
    for chunk in RrdReader(Path(path)).stream().to_chunks():
        entity = str(chunk.entity_path).lstrip("/")
        times = found.setdefault(entity, [])
        if TIMELINE in chunk.timeline_names:
            column = chunk.to_record_batch().column(TIMELINE)
            times.extend(v / 1e9 for v in column.cast("int64").to_pylist() if v is not None)
    return {entity: sorted(times) for entity, times in found.items()}


def recording_ids(path: Path) -> list[tuple[str, str]]:
    """``(application_id, recording_id)`` of each recording in an ``.rrd`` file."""
    from rerun.chunk import RrdReader

    return [(e.application_id, e.recording_id) for e in RrdReader(Path(path)).recordings()]


def open_viewer(path: Path) -> None:
    """Starts the Rerun viewer on ``path`` in the background.

    Raises:
        RecordingError: the viewer cannot be started.
    """
    import shutil
    import subprocess
    import sys

    viewer = shutil.which("rerun") or str(Path(sys.executable).with_name("rerun"))
    try:
        subprocess.Popen(
            [viewer, str(path)], start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
    except OSError as exc:
        raise RecordingError(
            f"cannot start the Rerun viewer ({viewer}): {exc.strerror or exc}; "
            f"open the recording yourself with: rerun {path}"
        ) from None
