"""The ``hri_scenario`` fixture: users' own scenario tests, registered by :mod:`hritest.pytest_plugin`.

Imports only pytest at module level (the plugin is imported in every pytest run); a spec compiles
the first time a test asks for it, once per session.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import pytest

from hritest.errors import HritestError

_domains_key = pytest.StashKey[dict]()


def _domain(config: pytest.Config, spec: Path) -> Any:
    """The compiled spec, once per spec per session (a spec that does not compile fails each of its tests)."""
    cache = config.stash.setdefault(_domains_key, {})
    if spec not in cache:
        from hritest.domain import load_domain

        try:
            cache[spec] = load_domain(spec)
        except HritestError as exc:
            cache[spec] = exc
    found = cache[spec]
    if isinstance(found, Exception):
        raise found
    return found


@pytest.fixture
def hri_scenario(request: pytest.FixtureRequest) -> Callable[..., tuple[Any, Any]]:
    """A factory that simulates one scenario: ``evaluation, rollout = hri_scenario(spec, theta, seed=0)``.

    ``spec`` is a spec file (relative paths from the rootdir); ``theta`` the raw scenario parameters,
    a sequence in the order ``hritest show`` lists or a mapping from those labels to values. Returns
    the :class:`hritest.records.Evaluation` (``status``, ``objective``, ``measures``, ``metrics``,
    ``failure``) and the Rollout (None when the scenario did not simulate). Specs compile once per
    session::

        def test_goals_stay_apart(hri_scenario):
            evaluation, rollout = hri_scenario("specs/teleop.yaml", [0.6, 0.05, 0.6, 0.1, 0, 0, 0, 0, 0])
            assert rollout.metrics["min_goal_distance"] > 0.05
    """
    config = request.config

    def simulate(
        spec: str | os.PathLike[str], theta: Sequence[float] | Mapping[str, float], seed: int = 0
    ) -> tuple[Any, Any]:
        import numpy as np

        from hritest.evaluate import evaluate_with_rollout

        domain = _domain(config, (config.rootpath / spec).resolve())
        labels = list(domain.space.labels)
        if isinstance(theta, Mapping):
            missing = [label for label in labels if label not in theta]
            extra = [key for key in theta if key not in labels]
            if missing or extra:
                raise ValueError(
                    f"hri_scenario: theta for {spec} needs exactly {', '.join(labels)}; "
                    f"missing {missing or 'none'}, unknown {extra or 'none'}"
                )
            theta = [theta[label] for label in labels]
        values = np.asarray(theta, dtype=float)
        if values.shape != (len(labels),):
            raise ValueError(
                f"hri_scenario: {spec} needs {len(labels)} theta values ({', '.join(labels)}), got {values.size}"
            )
        return evaluate_with_rollout(domain, values, seed=seed)

    return simulate
