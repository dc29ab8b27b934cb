"""The outcome digest: what decides a scenario's outcome, digested part by part.

A corpus entry replays a stored scenario; whether it still fails depends on the compiled scenario
space, the constraints that repair it and the units of the repair's cost, the task and policies
(their references, params and source files), the world model files, and the objective, measure and
failure expressions. It does not
depend on comments, formatting or search settings, so those are left out: editing them changes
nothing here. Each part is digested on its own so that a changed entry can say *what* changed.
"""

from __future__ import annotations

import hashlib
import json
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

PART_DIGITS = 16  # each part's digest is stored shortened: it only has to tell "changed" from "not"


@dataclass(frozen=True, kw_only=True)
class OutcomeDigest:
    """``parts`` maps each outcome-relevant part of a domain to its digest; ``digest`` covers them all."""

    digest: str
    parts: Mapping[str, str]


def outcome_digest(domain: Any) -> OutcomeDigest:
    """The outcome digest of a compiled :class:`hritest.domain.Domain`.

    Raises:
        OSError: a plugin or world model file that cannot be read.
    """
    spec = domain.spec
    world = domain.world
    parts: dict[str, Any] = {
        "scenario space": [[p.name, p.bind, list(p.bounds), p.size] for p in spec.parameters],
        "scene": {
            "objects": [o.model_dump() for o in spec.objects],
            "workspace": spec.workspace.model_dump() if spec.workspace else None,
            "world": spec.world.model_dump() if spec.world else None,
        },
        "constraints": [c.model_dump() for c in spec.constraints],
        "repair": spec.repair.model_dump(),
        "task": spec.task.model_dump(),
        "robot policy": spec.robot.model_dump(),
        "human policy": spec.human.model_dump(),
        "task plugin source": _source(domain.task_cls),
        "robot plugin source": _source(domain.robot_cls),
        "human plugin source": _source(domain.human_cls),
        "world model files": _files(
            [] if world is None else [world.model, None if world.arm is None else world.arm.mjcf]
        ),
        "objective": spec.objective.expr,
        "measures": [[m.name, m.expr] for m in spec.measures],
        "failure condition": spec.failure,
    }
    digests = {name: _digest(value)[:PART_DIGITS] for name, value in parts.items()}
    return OutcomeDigest(digest=_digest(digests), parts=digests)


def _digest(value: Any) -> str:
    data = value if isinstance(value, bytes) else json.dumps(value, sort_keys=True, default=str).encode()
    return hashlib.sha256(data).hexdigest()


def _source(cls: type) -> str:
    """The digest of the files a plugin class comes from: its module's file, or every ``.py`` file of
    the top-level package it belongs to (an installed package such as ``hritest_plugins``, whose
    classes import helpers from its other modules)."""
    module = sys.modules.get(cls.__module__)
    file = getattr(module, "__file__", None)
    if file is None:
        return _digest(cls.__qualname__)  # defined where no file holds it (a test's own class)
    package = (getattr(module, "__package__", None) or "").split(".")[0]
    top = sys.modules.get(package)
    root = Path(top.__file__).parent if package and getattr(top, "__file__", None) else None
    files = sorted(root.rglob("*.py")) if root is not None else [Path(file)]
    base = root if root is not None else Path(file).parent
    return _digest([[str(f.relative_to(base)), _digest(f.read_bytes())] for f in files])


def _files(paths: list[str | None]) -> list[str | None]:
    return [None if p is None else _digest(Path(p).read_bytes()) for p in paths]
