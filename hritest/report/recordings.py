"""The failures' Rerun recordings under ``<run>/recordings/``, made once per scenario."""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hritest.records import EvaluationRecord
from hritest.report.run import RunData
from hritest.rundir import atomic_write


@dataclass(frozen=True)
class Recorded:
    """A failure's recording and what its replay showed when it was made: ``matches`` says whether
    the re-simulation reproduced the stored outcome (None: not known, a recording left behind by
    ``hritest replay``); ``fresh`` whether it was made by this report rather than reused."""

    path: Path
    matches: bool | None
    differs: tuple[str, ...] = ()
    fresh: bool = False


REPLAYS = "replays.json"  # in recordings/: each recording's scenario digest and replay verdict


def record_failures(data: RunData, failures: Sequence[EvaluationRecord]) -> dict[int, Recorded]:
    """Re-simulates each failure (its stored raw theta and seed) into ``<run>/recordings/<id>.rrd``,
    unless a recording of that very scenario is there already (made by the search's own report, or
    an earlier one): recordings are made once per scenario."""
    from hritest.recording import check_writable, write_recording
    from hritest.records import scenario_digest
    from hritest.replay import replay_record

    if not failures:
        return {}
    folder = data.path / "recordings"
    check_writable(folder / f"{failures[0].index}.rrd")
    known = _replays(folder)
    done, domain = {}, None
    for record in failures:
        path = folder / f"{record.index}.rrd"
        entry = known.get(str(record.index), {})
        digest = scenario_digest(data.meta["spec_digest"], record.theta_repaired, record.seed)
        if path.is_file() and entry.get("digest") == digest:
            done[record.index] = Recorded(path, entry.get("matches"), tuple(entry.get("differs", ())))
            continue
        domain = domain or data.domain()
        replay = replay_record(domain, record, spec_digest=data.meta["spec_digest"])
        write_recording(
            path,
            domain=domain,
            evaluation=replay.evaluation,
            rollout=replay.rollout,
            recording_id=replay.digest,
            title=f"{data.spec.name}: failure {record.index} ({data.name})",
        )
        differs = tuple(c.name for c in replay.checks if not c.ok)
        done[record.index] = Recorded(path, replay.matches, differs, fresh=True)
        known[str(record.index)] = {"digest": digest, "matches": replay.matches, "differs": list(differs)}
    atomic_write(folder / REPLAYS, json.dumps(known, indent=1))
    return done


def _replays(folder: Path) -> dict[str, Any]:
    """The recordings' index; an unreadable one only means re-simulating (it is rewritten)."""
    try:
        data = json.loads((folder / REPLAYS).read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}
